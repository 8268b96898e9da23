"""The tables of a batch: ``summary.json``, ``summary.md`` and one comparison plot
``summary.png``, all written atomically into the batch's output folder."""

from __future__ import annotations

import math
from pathlib import Path
from typing import TYPE_CHECKING, Any

from gtvo.core.atomic import write_json, write_text

if TYPE_CHECKING:
    from gtvo.report import RunReport

#: The figures of a log's report (:class:`gtvo.report.RunReport`) copied into its summary row.
REPORT_FIELDS: tuple[str, ...] = ("sequence", "mode", "tracker_solver", "frames", "keyframes", "seconds", "frames_per_second",
                                  "tracking_failures", "lost_frames", "ate_rmse_m", "drift_percent",
                                  "kitti_translation_percent", "kitti_rotation_deg_per_100m", "path_length_m")

#: Columns of ``summary.md``: (row key, heading, format).
TABLE: tuple[tuple[str, str, str], ...] = (
    ("name", "log", "{}"), ("status", "status", "{}"), ("frames", "frames", "{}"), ("seconds", "s", "{:.1f}"),
    ("frames_per_second", "frames/s", "{:.2f}"), ("keyframes", "keyframes", "{}"),
    ("tracking_failures", "failures", "{}"), ("lost_frames", "lost", "{}"), ("ate_rmse_m", "ATE m", "{:.4f}"),
    ("sim3_ate_rmse_m", "Sim(3) ATE m", "{:.4f}"), ("drift_percent", "drift %", "{:.2f}"),
    ("kitti_translation_percent", "segment drift %", "{:.2f}"), ("config_id", "config", "`{}`"),
)


def summary_row(log: Any, config_id: str, out: Path, result: dict[str, Any], report: RunReport | None,
                resumed: bool) -> dict[str, Any]:
    """One log's row: its identity, status, the figures of its report (:data:`REPORT_FIELDS`, None
    where absent; ``sim3_ate_rmse_m`` is the report's ``ate_sim3_rmse_m``) and the worker's wall
    time from its record (``batch.json``)."""
    row: dict[str, Any] = {"name": log.name, "path": str(log.path), "format": log.format, "config_id": config_id,
                           "config_overrides": log.config, "status": result["status"], "resumed": resumed,
                           "out": str(out)}
    if result["status"] == "done":
        record = result.get("record", {})
        for key in REPORT_FIELDS:
            row[key] = (report or {}).get(key)  # type: ignore[misc]
        # the report's Sim(3)-aligned ATE, under the summary's older name
        row["sim3_ate_rmse_m"] = (report or {}).get("ate_sim3_rmse_m")
        row["wall_seconds"] = record.get("wall_seconds")
    else:
        row["error"] = result.get("error")
        row["error_type"] = result.get("error_type")
        if "traceback" in result:
            row["traceback"] = result["traceback"]
    return row


def write_summary(out: Path, info: dict[str, Any], rows: list[dict[str, Any]]) -> dict[str, Path]:
    """Write ``summary.json`` (``info`` + every row), ``summary.md`` and ``summary.png`` into ``out``."""
    paths = {"json": out / "summary.json", "md": out / "summary.md", "png": out / "summary.png"}
    plot_summary(rows, paths["png"])
    write_text(paths["md"], summary_markdown(info, rows))
    write_json(paths["json"], {**info, "logs": [_finite(r) for r in rows]})
    return paths


def summary_markdown(info: dict[str, Any], rows: list[dict[str, Any]]) -> str:
    """The summary as a Markdown table, with the failed logs' errors below it."""
    failed = [r for r in rows if r["status"] != "done"]
    lines = [f"# gtvo batch: {info.get('spec')}", "",
             f"{len(rows)} logs, {len(rows) - len(failed)} done, {len(failed)} failed; run on {info.get('runner')} "
             f"({info.get('workers')} workers) in {info.get('wall_seconds', 0.0):.1f} s. ATE: SE(3)-aligned, "
             f"Sim(3) ATE: aligned with scale, segment drift: KITTI segment translation error. "
             f"Resumed logs are marked *.", "",
             *([f"**Partial: the batch was interrupted; {info.get('logs_not_run', 0)} logs were not run.**", ""]
               if info.get("partial") else []),
             "| " + " | ".join(h for _, h, _ in TABLE) + " |",
             "|" + "|".join("---" for _ in TABLE) + "|"]
    for r in rows:
        cells = [_cell(r.get(k), fmt) for k, _, fmt in TABLE]
        if r.get("resumed"):
            cells[0] += " *"
        lines.append("| " + " | ".join(cells) + " |")
    if failed:
        lines += ["", "## Failed logs", ""]
        lines += [f"* `{r['name']}` ({r['path']}): {r.get('error')}" for r in failed]
    return "\n".join(lines) + "\n"


def plot_summary(rows: list[dict[str, Any]], path: Path) -> Path:
    """One comparison figure: frames per second, ATE (SE(3) and Sim(3)) and segment drift per log
    (horizontal bars, one row per log; a failed log says so, a missing figure is left empty)."""
    from gtvo.io.plots import _new_figure, _save  # noqa: PLC0415

    names = [r["name"] for r in rows]
    n = len(rows)
    fig = _new_figure((12.0, 1.2 + 0.35 * max(n, 3)))
    panels = (("frames per second", [("frames_per_second", "tab:blue", "frames/s")]),
              ("ATE [m]", [("ate_rmse_m", "tab:orange", "SE(3)"), ("sim3_ate_rmse_m", "tab:green", "Sim(3)")]),
              ("drift [%]", [("kitti_translation_percent", "tab:red", "KITTI segments"),
                                     ("drift_percent", "tab:purple", "final / path")]))
    y = list(range(n))
    for k, (title, series) in enumerate(panels):
        ax = fig.add_subplot(1, 3, k + 1)
        h = 0.8 / len(series)
        for j, (key, colour, label) in enumerate(series):
            ys = [v - 0.4 + h * (j + 0.5) for v in y]
            vals = [_number(r.get(key)) for r in rows]
            ax.barh(ys, [0.0 if v is None else v for v in vals], height=h, color=colour, label=label)
        for i, r in enumerate(rows):
            if r["status"] != "done":
                ax.text(0.0, i, f" {r['status']}", va="center", ha="left", color="tab:red", fontsize=8)
        ax.set_yticks(y)
        ax.set_yticklabels(names if k == 0 else [""] * n, fontsize=8)
        ax.invert_yaxis()
        ax.set_title(title, fontsize=10)
        ax.grid(True, axis="x", alpha=0.3)
        if len(series) > 1:
            ax.legend(loc="best", fontsize=7)
    fig.tight_layout()
    return _save(fig, path)


def _number(v: Any) -> float | None:
    return float(v) if isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) else None


def _cell(v: Any, fmt: str) -> str:
    if v is None:
        return "-"
    try:
        return fmt.format(v)
    except (ValueError, TypeError):
        return str(v)


def _finite(obj: Any) -> Any:
    if isinstance(obj, dict):
        return {k: _finite(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_finite(v) for v in obj]
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    return obj
