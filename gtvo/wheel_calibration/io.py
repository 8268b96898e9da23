"""Readers of motion tables: the Freiburg/Octave text matrix and a plain ``dx dy dtheta`` table.

Both formats are whitespace-separated rows of three numbers; ``#`` starts a comment. An Octave
header (``# rows: N`` / ``# columns: 3``) is checked against the data when present.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from gtvo.errors import InputError, not_a_file

_HEADER = re.compile(r"#\s*(rows|columns)\s*:\s*(\S+)")


def read_motions(path: str | Path) -> NDArray[np.float64]:
    """Read an (N, 3) array of motions ``dx dy dtheta`` from ``path``.

    Raises InputError naming ``path:line`` for a row that is not three finite numbers, and naming the
    file for a missing/unreadable/empty file or a header that disagrees with the data.
    """
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except (FileNotFoundError, IsADirectoryError):
        raise not_a_file(path, "motions file") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"cannot read motions ({exc.__class__.__name__}: {exc})", path) from None
    rows: list[list[float]] = []
    header: dict[str, str] = {}
    for lineno, raw in enumerate(text.splitlines(), start=1):
        line = raw.strip()
        if line.startswith("#"):
            m = _HEADER.match(line)
            if m:
                header[m.group(1)] = m.group(2)
            continue
        line = line.split("#", 1)[0].strip()
        if not line:
            continue
        fields = line.replace(",", " ").split()
        if len(fields) != 3:
            raise InputError(f"expected 3 numbers (dx dy dtheta), got {len(fields)}: {raw.strip()!r}", path, lineno)
        try:
            values = [float(f) for f in fields]
        except ValueError:
            raise InputError(f"not a number in {raw.strip()!r}", path, lineno) from None
        if not all(np.isfinite(values)):
            raise InputError(f"non-finite value in {raw.strip()!r}", path, lineno)
        rows.append(values)
    if not rows:
        raise InputError("no motions (empty file)", path)
    motions = np.array(rows, dtype=np.float64)
    for key, expected in (("rows", motions.shape[0]), ("columns", 3)):
        if key in header and header[key] != str(expected):
            raise InputError(f"header says {key}: {header[key]} but the file has {expected}", path)
    return motions


def read_motion_pair(odom_path: str | Path, reference_path: str | Path) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Read raw odometry and reference motions; InputError if their lengths differ."""
    odom = read_motions(odom_path)
    ref = read_motions(reference_path)
    if odom.shape[0] != ref.shape[0]:
        raise InputError(f"{odom.shape[0]} odometry motions but {ref.shape[0]} reference motions in {reference_path}",
                         odom_path)
    return odom, ref
