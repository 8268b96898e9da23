"""``gtvo batch``: the same job on a fleet of logs, each run as ``gtvo run`` would into
``OUT/<name>/``, with a summary table and one comparison plot (docs/batch.md).

>>> result = batch("logs/", "out/", jobs=2)        # doctest: +SKIP
>>> result.failed                                  # doctest: +SKIP
[]

Parts: :mod:`gtvo.batching.spec` (which logs), :mod:`gtvo.batching.overrides` (per-log settings and
the configuration's identity), :mod:`gtvo.batching.runners` (process pool or Ray),
:mod:`gtvo.batching.summary` (``summary.json``, ``summary.md``, ``summary.png``). Nothing here
imports numpy at module level: pool and Ray workers import this package before they set their
BLAS threads.
"""

from __future__ import annotations

import dataclasses

import json
import os
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from gtvo.core.atomic import ensure_output_dir, output_lock, tidy_on_failure
from gtvo.core.paths import identity, link_problem, resolved, same_or_inside
from gtvo.batching.overrides import apply_overrides, canonical, config_identity
from gtvo.batching.runners import RECORD_NAME, failure, require_ray, run_in_pool, run_on_ray, start_ray
from gtvo.batching.spec import LogSpec, read_spec
from gtvo.batching.summary import summary_row, write_summary
from gtvo.errors import InputError
from gtvo.io.log_settings import log_wheel_settings, wheel_settings_line

__all__ = ["BatchResult", "LogSpec", "batch", "read_spec"]


@dataclass(frozen=True)
class BatchResult:
    """What :func:`batch` did.

    Attributes:
        out: the batch's output folder.
        rows: one summary row per log, in SPEC order (as in ``summary.json``).
        failed: names of the logs that failed.
        resumed: names of the logs skipped by ``resume`` (their outputs were complete).
        summary: the written files (``"json"``, ``"md"``, ``"png"``).
    """

    out: Path
    rows: list[dict[str, Any]]
    failed: list[str] = field(default_factory=list)
    resumed: list[str] = field(default_factory=list)
    summary: dict[str, Path] = field(default_factory=dict)

    @property
    def ok(self) -> bool:
        """True when every log ran."""
        return not self.failed


def batch(spec: str | Path | list[Any], out: str | Path, jobs: int | None = None, ray: str | None = None,
          resume: bool = False, progress: bool = True, config: Any = None, max_frames: int | None = None,
          frame_step: int = 1, loop_closure: bool = False) -> BatchResult:
    """Run every log of ``spec`` as :func:`gtvo.run` would, into ``out/<name>/``, and tabulate them.

    Args:
        spec: a folder of logs, a YAML file listing them, or that list itself (:mod:`gtvo.batching.spec`).
        out: the batch's output folder (``summary.json``, ``summary.md``, ``summary.png``, one
            folder per log).
        jobs: logs run at once (default: the number of cores); workers run BLAS single-threaded.
        ray: None for a local process pool; ``"auto"`` (a running Ray cluster), ``"local"`` (a
            local Ray with ``jobs`` CPUs) or a cluster address to run the logs as Ray tasks.
            Workers must see the logs and ``out`` under the same paths.
        resume: skip logs whose outputs are complete and were made by the same job (log, format,
            options, configuration identity).
        progress: a progress bar over the logs.
        config: the base :class:`gtvo.config.OdometryConfig` (default ``OdometryConfig()``, as
            :func:`gtvo.run`); a log's ``config`` overrides are applied to it.
        max_frames, frame_step, loop_closure: as :func:`gtvo.run`, for every log that does not set its own.

    Returns:
        A :class:`BatchResult`; a log that fails is in ``failed`` (with its error in its row).

    Raises:
        InputError: a bad SPEC (missing, malformed, unknown setting, duplicate names), a bad
            ``jobs`` or unusable ``out``: before any log runs.
        DependencyError: ``ray`` given but Ray is not installed (``pip install "gtvo[ray]"``).
    """
    t0 = time.perf_counter()
    workers = _check_jobs(jobs)
    if ray is not None:
        require_ray()  # a missing extra is said before any work
    if link_problem(out) is not None:
        raise InputError(f"output folder is {link_problem(out)}", path=out)
    if not isinstance(spec, list) and Path(spec).is_dir() and identity(out) == identity(spec):
        raise InputError("output folder is the SPEC folder itself; the logs' outputs would mix with the logs: "
                         "choose another (a new folder, or one inside it)", path=out)
    out_path = resolved(out, "output folder")
    logs = read_spec(spec, exclude=(out_path,))
    _check_out_outside_logs(out_path, logs)  # before anything is made there
    with tidy_on_failure(), output_lock(out_path, SUMMARY_NAMES):
        out_dir = ensure_output_dir(out_path)
        jobs_list = [_job(log, out_dir, config, max_frames, frame_step, loop_closure,
                          where=f"{_where(spec)}, log {log.name!r}") for log in logs]
        _check_no_repeats(logs, jobs_list, _where(spec))
        _discard_leftovers(jobs_list)
        rows, todo = _plan(logs, jobs_list, resume)
        resumed = [r["name"] for r in rows if r is not None and r["resumed"]]
        n_workers = max(1, min(workers, len(todo)))
        info = {"spec": _where(spec), "out": str(out_dir), "runner": "pool" if ray is None else f"ray ({ray})",
                "workers": n_workers if ray is None else (workers if ray == "local" else "cluster")}
        try:
            _run(logs, jobs_list, todo, rows, n_workers if ray is None else workers, ray, progress)
        except KeyboardInterrupt:
            _write_partial_summary(out_dir, info, logs, jobs_list, rows, t0)
            raise
        done_rows = [r for r in rows if r is not None]
        failed = [r["name"] for r in done_rows if r["status"] != "done"]
        info.update({"wall_seconds": time.perf_counter() - t0, "logs_total": len(done_rows),
                     "logs_failed": len(failed), "logs_resumed": len(resumed)})
        paths = write_summary(out_dir, info, done_rows)
    return BatchResult(out=out_dir, rows=done_rows, failed=failed, resumed=resumed, summary=paths)


#: The batch's own files in its output folder.
SUMMARY_NAMES: tuple[str, ...] = ("summary.json", "summary.md", "summary.png")


def _discard_leftovers(jobs_list: list[dict[str, Any]]) -> None:
    """Remove what writers killed before (an earlier batch's workers, a run) left beside or in the
    logs' output folders: each folder's lock taken for a moment (:func:`gtvo.core.atomic.output_lock`),
    so a folder another process is writing is left to it (that log's run then says so)."""
    for job in jobs_list:
        try:
            with output_lock(job["out"], (RECORD_NAME,)):
                pass
        except InputError:
            pass


def _check_out_outside_logs(out_dir: Path, logs: list[LogSpec]) -> None:
    """A one-line :class:`InputError` when the batch's output folder is a log's folder or inside
    one (by file identity: ``..``, symbolic links, bind mounts): nothing is written into a log."""
    for log in logs:
        if log.problem is None and log.path.is_dir() and same_or_inside(out_dir, log.path):
            where = "the log" if identity(out_dir) == identity(log.path) else "inside the log"
            raise InputError(f"output folder is {where} {log.path} ({log.name!r}); outputs there would mix with "
                             f"its data: choose another --out", path=out_dir)


def _check_no_repeats(logs: list[LogSpec], jobs_list: list[dict[str, Any]], where: str) -> None:
    """A one-line :class:`InputError` when two entries are the same log (by file identity) with the
    same format, options and settings: the second would only repeat the first."""
    seen: dict[Any, str] = {}
    for log, job in zip(logs, jobs_list):
        if log.problem is not None:
            continue
        key = (identity(log.path), json.dumps({k: v for k, v in job["key"].items() if k != "path"}, sort_keys=True,
                                              default=str))
        if key in seen:
            raise InputError(f"{where}: logs {seen[key]!r} and {log.name!r} are the same log ({log.path}) with the "
                             f"same settings; give it once, or give each its own settings")
        seen[key] = log.name


def _write_partial_summary(out_dir: Path, info: dict[str, Any], logs: list[LogSpec],
                           jobs_list: list[dict[str, Any]], rows: list[dict[str, Any] | None], t0: float) -> None:
    """After Ctrl-C: the summary of what finished, marked ``"partial": true``, the other logs as not
    run (so that no earlier summary is left beside this batch's outputs). A second Ctrl-C is held
    back while it is written (the three files come from one batch)."""
    from gtvo.batching.runners import failure  # noqa: PLC0415
    from gtvo.core.atomic import deferred_interrupts  # noqa: PLC0415

    with deferred_interrupts():
        done_rows = []
        for i, (log, job) in enumerate(zip(logs, jobs_list)):
            row = rows[i]
            if row is None:
                row = summary_row(log, job["key"]["config_id"], Path(job["out"]),
                                  failure(InterruptedError("not run: the batch was interrupted")), None, False)
                row["status"] = "not run"
            done_rows.append(row)
        failed = [r["name"] for r in done_rows if r["status"] == "failed"]
        info = {**info, "partial": True, "wall_seconds": time.perf_counter() - t0, "logs_total": len(done_rows),
                "logs_failed": len(failed), "logs_not_run": sum(1 for r in done_rows if r["status"] == "not run"),
                "logs_resumed": sum(1 for r in done_rows if r.get("resumed"))}
        try:
            write_summary(out_dir, info, done_rows)
        except Exception:  # noqa: BLE001 - interrupted: the interrupt is what is reported
            pass


def _plan(logs: list[LogSpec], jobs_list: list[dict[str, Any]], resume: bool,
          ) -> tuple[list[dict[str, Any] | None], list[int]]:
    """Rows known before running (logs that are no logs fail; complete ones are resumed) and the
    indices of the logs to run."""
    rows: list[dict[str, Any] | None] = [None] * len(logs)
    todo: list[int] = []
    for i, (log, job) in enumerate(zip(logs, jobs_list)):
        if log.problem is not None:
            rows[i] = summary_row(log, job["key"]["config_id"], Path(job["out"]),
                                  failure(InputError(log.problem)), None, False)
        elif resume and _complete(Path(job["out"]), job["key"]):
            record = _read_json(Path(job["out"]) / RECORD_NAME)
            rows[i] = _row_of(log, job, {"status": "done", "record": record}, resumed=True)
        else:
            todo.append(i)
    return rows, todo


def _run(logs: list[LogSpec], jobs_list: list[dict[str, Any]], todo: list[int], rows: list[dict[str, Any] | None],
         workers: int, ray: str | None, progress: bool) -> None:
    """Run the logs ``todo`` on the pool or on Ray, filling their ``rows`` as they finish."""
    if not todo:
        return
    ray_module, started = start_ray(ray, workers) if ray is not None else (None, False)
    bar = _progress_bar(len(logs), len(logs) - len(todo), progress)

    def on_done(k: int, result: dict[str, Any]) -> None:
        i = todo[k]
        rows[i] = _row_of(logs[i], jobs_list[i], result, resumed=False)
        if bar is not None:
            if result["status"] != "done":
                bar.write(f"gtvo batch: {logs[i].name} failed: {result.get('error')}")
            bar.update(1)
            bar.set_postfix(failed=sum(1 for r in rows if r is not None and r["status"] != "done"))

    chosen = [jobs_list[i] for i in todo]
    try:
        if ray is None:
            run_in_pool(chosen, workers, on_done)
        else:
            run_on_ray(chosen, on_done)
    finally:
        if bar is not None:
            bar.close()
        if started:
            ray_module.shutdown()


def _check_jobs(jobs: int | None) -> int:
    if jobs is None:
        return os.cpu_count() or 1
    if isinstance(jobs, bool) or not isinstance(jobs, int) or jobs < 1:
        raise InputError(f"jobs must be an integer >= 1, got {jobs!r}")
    return jobs


def one_core_per_log(config: Any) -> Any:
    """``config`` for one log of a batch: ``window.parallel: auto`` runs as ``false`` (``--jobs N``
    on N cores keeps one core per log); ``true``, which a log's config may ask for, stays."""
    if config.window.parallel != "auto":
        return config
    return dataclasses.replace(config, window=dataclasses.replace(config.window, parallel=False))


def _job(log: LogSpec, out_dir: Path, base: Any, max_frames: int | None, frame_step: int, loop_closure: bool,
         where: str) -> dict[str, Any]:
    """The worker's job for ``log``: resolved configuration, options, output folder, identity key."""
    from gtvo.config import OdometryConfig  # noqa: PLC0415

    config = apply_overrides(base if base is not None else OdometryConfig(), log.config, where=where)
    config = one_core_per_log(config)
    if log.problem is None:  # the log folder's wheel.yaml, read like its calibration
        config, wheel_file = log_wheel_settings(log.path, config)
        if wheel_file is not None:
            print(f"gtvo batch: {log.name}: {wheel_settings_line(wheel_file)}", file=sys.stdout)
    options = {"max_frames": max_frames, "frame_step": frame_step, "loop_closure": loop_closure,
               "camera": None, "ground_truth": None, **log.options}
    target = out_dir / log.name
    if log.problem is None and (same_or_inside(target, log.path) or same_or_inside(log.path, target)):
        raise InputError(f"{where}: the output folder {target} would overlap the log {log.path}; choose another --out")
    key = canonical({"path": str(log.path), "format": log.format, "options": options,
                     "config_id": config_identity(config)})
    return {"name": log.name, "path": str(log.path), "format": log.format, "out": str(target), "config": config,
            "options": options, "key": key}


def _complete(out: Path, key: dict[str, Any]) -> bool:
    """True when ``out`` holds a finished run of the job ``key`` (its record is written last)."""
    if not ((out / "report.json").is_file() and (out / "trajectory.tum").is_file()):
        return False
    record = _read_json(out / RECORD_NAME)
    return record is not None and record.get("key") == key


def _row_of(log: LogSpec, job: dict[str, Any], result: dict[str, Any], resumed: bool) -> dict[str, Any]:
    """The log's summary row, from its run's report (:func:`gtvo.report.read_report`)."""
    from gtvo.report import read_report  # noqa: PLC0415 - heavy: imported when a log has finished

    out = Path(job["out"])
    report = None
    if result["status"] == "done":
        try:
            report = read_report(out / "report.json")
        except InputError:
            result = failure(InputError("the run finished but its report.json cannot be read",
                                        path=out / "report.json"))
    return summary_row(log, job["key"]["config_id"], out, result, report, resumed)


def _read_json(path: Path) -> dict[str, Any] | None:
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    return data if isinstance(data, dict) else None


def _progress_bar(total: int, initial: int, progress: bool) -> Any:
    if not progress:
        return None
    import sys  # noqa: PLC0415

    from tqdm import tqdm  # noqa: PLC0415

    return tqdm(total=total, initial=initial, desc="gtvo batch", unit="log", dynamic_ncols=True, file=sys.stderr)


def _where(spec: str | Path | list[Any]) -> str:
    return "SPEC list" if isinstance(spec, list) else str(spec)
