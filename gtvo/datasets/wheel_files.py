"""Wheel odometry files: ``wheel_odometry.csv`` beside a sequence (or ``--wheel-odometry FILE``), its
writer, and the options every wheel reader takes (docs/wheel_odometry.md, "The CSV file").

The file: a header line, then one row per reading, comma-separated::

    time,x,y,theta          # the base's planar pose in its odometry frame (REP 103: m, rad)
    time,left,right         # cumulative wheel arc lengths (m), or ticks with wheel.tick_scale

Times are seconds in the sequence's clock. ``#`` starts a comment line; blank lines are skipped.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from gtvo.config.sections.wheel import WheelReadOptions
from gtvo.datasets._common import parse_float_table, read_rows
from gtvo.datasets.wheel import WHEEL_COLUMNS, WheelOdometry, check_readings, check_speed
from gtvo.errors import InputError

#: The name of the wheel odometry file beside a sequence (inside its folder).
WHEEL_CSV = "wheel_odometry.csv"


def read_wheel_csv(path: str | Path, options: WheelReadOptions = WheelReadOptions()) -> WheelOdometry:
    """Read a wheel odometry CSV (module doc).

    Raises:
        InputError: one line naming the file and the line: a header that is neither
            ``time,x,y,theta`` nor ``time,left,right``, a row of the wrong width, not a number, NaN,
            a time not after the previous row's, a gap longer than ``options.max_gap``, a wheel
            (after ``options.tick_scale``) or the base faster than ``options.max_speed``.
    """
    path = Path(path)
    rows = read_rows(path, 1, delimiter=",")
    if not rows:
        raise InputError("empty wheel odometry file: expected a header time,x,y,theta or time,left,right", path)
    header = [f.lower() for f in rows[0].fields]
    kind = next((k for k, cols in WHEEL_COLUMNS.items() if header == ["time", *cols]), None)
    if kind is None:
        raise InputError(f"the header is {','.join(rows[0].fields)!r}: expected time,x,y,theta (planar pose) or "
                         "time,left,right (wheel arcs)", path, rows[0].line)
    data = rows[1:]
    for row in data:
        if len(row.fields) != len(header):
            raise InputError(f"expected {len(header)} values ({','.join(header)}), got {len(row.fields)}",
                             path, row.line)
    table = parse_float_table(data, path, slice(None)) if data else np.zeros((0, len(header)))
    lines = [r.line for r in data]
    times, values = check_readings(table[:, 0], table[:, 1:], kind, str(path), rows=lines, row_name="line",
                                   max_gap=options.max_gap)
    if kind == "arcs":
        values = values * options.tick_scale
    check_speed(times, values, kind, str(path), lines, "line", options.max_speed)
    return WheelOdometry(times, kind, values, str(path), options.nominal_baseline)  # type: ignore[arg-type]


def write_wheel_csv(odometry: WheelOdometry, path: str | Path) -> Path:
    """Write ``odometry`` as a wheel odometry CSV (arcs in metres: read back with ``tick_scale`` 1)."""
    path = Path(path)
    columns = ",".join(("time", *WHEEL_COLUMNS[odometry.kind]))
    table = np.column_stack([odometry.times, odometry.values])
    lines = [columns] + [",".join(f"{v:.17g}" for v in row) for row in table]
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path
