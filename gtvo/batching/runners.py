"""Where the logs of a batch run: a local process pool or Ray, each log in a worker process as
``gtvo run`` would run it.

This module imports nothing heavy at the top: a worker sets single-threaded BLAS (and numba)
before numpy is first imported (the pool's initializer; Ray's ``runtime_env``), since N workers
each running multithreaded BLAS on N cores oversubscribe them.
"""

from __future__ import annotations

import contextlib
import os
import signal
import threading
import time
import traceback
from pathlib import Path
from typing import Any, Callable, Iterator

from gtvo.core.interrupt import interrupts_held

#: Environment of every worker: single-threaded BLAS and numba (set before numpy is imported).
WORKER_ENV: dict[str, str] = {"OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1",
                              "NUMBA_NUM_THREADS": "1"}

#: The per-log record a finished log leaves in its output folder (written last).
RECORD_NAME = "batch.json"

#: Called with (index of the job, its result) as each log finishes.
OnDone = Callable[[int, dict[str, Any]], None]


def init_worker() -> None:
    """Process-pool initializer: single-threaded BLAS and numba in this worker; Ctrl-C is left to
    the parent, which ends the workers (no traceback from every worker). The parent starts its
    workers with SIGINT blocked (:func:`gtvo.core.interrupt.interrupts_held`), so a Ctrl-C to the process group while
    a worker starts up is dropped here rather than raised in its start-up."""
    os.environ.update(WORKER_ENV)
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})


def run_log(job: dict[str, Any]) -> dict[str, Any]:
    """Run one log as ``gtvo run`` would, into ``job["out"]``; never raises for a failing log.

    ``job`` holds ``name``, ``path``, ``format``, ``out``, ``config`` (a resolved
    :class:`gtvo.config.OdometryConfig`), ``options`` (``max_frames``, ``frame_step``,
    ``loop_closure``; the others go to :func:`gtvo.datasets.open_sequence`) and ``key`` (what
    makes the outputs this job's, for ``--resume``). On success the log's record (``batch.json``:
    the key, the Sim(3) ATE from the run's report (``ate_sim3_rmse_m``), the wall time, the
    worker's pid and BLAS threads) is written last into the output folder.

    Returns:
        ``{"status": "done", "record": {...}}`` or ``{"status": "failed", "error": "one line",
        "error_type": ..., "traceback": ... (for errors that are not gtvo's own)}``.
    """
    t0 = time.perf_counter()
    out = Path(job["out"])
    try:
        (out / RECORD_NAME).unlink(missing_ok=True)  # a re-run that fails must not look complete
        import cv2  # noqa: PLC0415

        cv2.setRNGSeed(0)  # OpenCV's global RNG (PnP RANSAC) as in a fresh `gtvo run` process
        from gtvo.datasets import open_sequence  # noqa: PLC0415
        from gtvo.core.atomic import write_json  # noqa: PLC0415
        from gtvo.config import as_config  # noqa: PLC0415
        from gtvo.io.plots import load_now  # noqa: PLC0415
        from gtvo.pipeline import run  # noqa: PLC0415

        load_now()  # the plots' imports here, not in a thread beside the run: one core per log

        opts = job["options"]
        open_opts = {k: v for k, v in opts.items()
                     if k not in ("max_frames", "frame_step", "loop_closure") and v is not None}
        from gtvo.datasets.imu_files import imu_read_options  # noqa: PLC0415

        open_opts.setdefault("wheel_options", as_config(job["config"]).wheel.read_options())
        open_opts.setdefault("imu_options", imu_read_options(as_config(job["config"]).imu))  # as gtvo run's
        seq = open_sequence(job["path"], format=job["format"], max_frames=opts.get("max_frames"), **open_opts)
        report = run(seq, out=out, config=job["config"], progress=False, frame_step=opts.get("frame_step", 1),
                     loop_closure=bool(opts.get("loop_closure", False)))
        record = {"name": job["name"], "key": job["key"], "sim3_ate_rmse_m": report.get("ate_sim3_rmse_m"),
                  "run_seconds": report["seconds"], "wall_seconds": time.perf_counter() - t0,
                  "worker_pid": os.getpid(), "blas_threads": blas_threads()}
        write_json(out / RECORD_NAME, record)
        return {"status": "done", "record": record}
    except KeyboardInterrupt:
        raise
    except Exception as exc:  # noqa: BLE001 - a failing log is reported and the others go on
        return failure(exc, time.perf_counter() - t0)


def blas_threads() -> int | None:
    """The most threads any BLAS library loaded in this process may use (None if none is loaded)."""
    from threadpoolctl import threadpool_info  # noqa: PLC0415

    counts = [int(p["num_threads"]) for p in threadpool_info() if p.get("user_api") == "blas"]
    return max(counts) if counts else None


def failure(exc: BaseException, seconds: float | None = None) -> dict[str, Any]:
    """The result of a log that failed with ``exc`` (one line; the traceback for unexpected errors)."""
    from gtvo.errors import GtvoError  # noqa: PLC0415

    message = " ".join(str(exc).split()) or type(exc).__name__
    result: dict[str, Any] = {"status": "failed", "error": message, "error_type": type(exc).__name__,
                              "wall_seconds": seconds}
    if not isinstance(exc, (GtvoError, OSError)):
        result["traceback"] = "".join(traceback.format_exception(exc))
    return result


def run_in_pool(jobs: list[dict[str, Any]], workers: int, on_done: OnDone,
                task: Callable[[dict[str, Any]], dict[str, Any]] = run_log) -> None:
    """Run ``jobs`` in a pool of ``workers`` fresh (spawned) processes; ``on_done`` per finished log.

    A worker process that dies (killed, out of memory, a crash in native code) breaks the whole
    pool, and every log it was running or had queued fails with it. Those logs are then run
    again one at a time, each in a pool of its own, so that only the log that kills its worker
    fails (with a line that says so) and the others finish.
    """
    from concurrent.futures.process import BrokenProcessPool  # noqa: PLC0415

    broken = _pool_round(list(range(len(jobs))), jobs, workers, on_done, task)
    for i in broken:
        again = _pool_round([i], jobs, 1, on_done, task)
        if again:
            on_done(i, failure(BrokenProcessPool("the worker process died while running this log (killed, out "
                                                 "of memory or a crash in native code)")))


def _pool_round(indices: list[int], jobs: list[dict[str, Any]], workers: int, on_done: OnDone,
                task: Callable[[dict[str, Any]], dict[str, Any]]) -> list[int]:
    """Run ``jobs[indices]`` in one pool; return the indices whose results a dead worker took."""
    import multiprocessing  # noqa: PLC0415
    from concurrent.futures import ProcessPoolExecutor, as_completed  # noqa: PLC0415
    from concurrent.futures.process import BrokenProcessPool  # noqa: PLC0415

    ctx = multiprocessing.get_context("spawn")  # no fork of a parent holding threads and BLAS state
    pool = ProcessPoolExecutor(max_workers=workers, mp_context=ctx, initializer=init_worker)
    broken: list[int] = []
    try:
        with interrupts_held():  # the workers start here (one per submit), inheriting SIGINT blocked
            futures = {pool.submit(task, jobs[i]): i for i in indices}
        for fut in as_completed(futures):
            try:
                result = fut.result()
            except BrokenProcessPool:
                broken.append(futures[fut])
                continue
            except Exception as exc:  # noqa: BLE001 - a result that could not come back
                result = failure(exc)
            on_done(futures[fut], result)
        pool.shutdown(wait=True)  # (a dead worker's pool has ended its other workers already)
    except BaseException:  # Ctrl-C or an error: stop the workers now rather than after their current logs
        with _interrupts_ignored():  # a second Ctrl-C must not leave workers running
            _terminate(pool)
            _discard_unfinished([jobs[i] for i in indices])
        raise
    _discard_unfinished([jobs[i] for i in broken])
    return sorted(broken)


#: Seconds a worker is given to end after SIGTERM before it is killed.
TERMINATE_TIMEOUT_S = 5.0


def _terminate(pool: Any) -> None:
    """Cancel the pending logs and end the pool's worker processes at once (SIGTERM, then SIGKILL
    after :data:`TERMINATE_TIMEOUT_S`), waiting until they are gone."""
    import gc  # noqa: PLC0415

    processes = list((getattr(pool, "_processes", None) or {}).values())  # shutdown() forgets them
    manager = getattr(pool, "_executor_manager_thread", None)
    pool.shutdown(wait=False, cancel_futures=True)
    for proc in processes:
        proc.terminate()
    deadline = time.monotonic() + TERMINATE_TIMEOUT_S
    for proc in processes:
        proc.join(timeout=max(0.0, deadline - time.monotonic()))
    for proc in processes:
        if proc.is_alive():
            proc.kill()
            proc.join()
    if manager is not None:  # it sees the workers gone and lets go of the pool's queues
        manager.join(timeout=TERMINATE_TIMEOUT_S)
    del processes, manager
    gc.collect()  # the queues' semaphores are released now, not left for multiprocessing's resource
    #               tracker to report as leaked once the command exits at once (gtvo.cli.entry_point)


def _discard_unfinished(jobs: list[dict[str, Any]]) -> None:
    """Remove what the ended workers left half-written of these logs' outputs (their staging
    folders, a half-swapped folder put back, a temporary ``batch.json``): ``--resume`` then meets
    only finished logs and clean folders."""
    from gtvo.core.atomic import discard_unfinished  # noqa: PLC0415

    discard_unfinished([Path(job["out"]) for job in jobs if "out" in job], file_names=(RECORD_NAME,))


@contextlib.contextmanager
def _interrupts_ignored() -> Iterator[None]:
    """SIGINT ignored during the block (the clean-up after a first Ctrl-C); main thread only."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)


def require_ray() -> Any:
    """Import and return ``ray``, or raise :class:`DependencyError` naming the extra."""
    from gtvo.errors import DependencyError  # noqa: PLC0415

    try:
        import ray  # noqa: PLC0415
    except ImportError as exc:
        raise DependencyError(f'--ray needs Ray, which is not installed ({exc}); install it: '
                              f'pip install "gtvo[ray]"') from None
    return ray


def start_ray(address: str, cpus: int) -> tuple[Any, bool]:
    """Connect to Ray: ``"auto"`` (a running cluster), ``"local"`` (start a local Ray with
    ``cpus`` CPUs, no dashboard) or a cluster address. An existing connection is used as it is.

    Returns:
        ``(ray, started)``: ``started`` when this call connected (so the caller disconnects).
    """
    import logging  # noqa: PLC0415

    from gtvo.errors import InputError  # noqa: PLC0415

    ray = require_ray()
    if ray.is_initialized():
        return ray, False
    kwargs: dict[str, Any] = {"logging_level": logging.WARNING, "log_to_driver": True}
    if address not in ("local", "auto"):
        check_reachable(address)
    try:
        if address == "local":
            ray.init(num_cpus=cpus, include_dashboard=False, **kwargs)
        else:
            ray.init(address=address, **kwargs)
    except (ConnectionError, ValueError, RuntimeError) as exc:
        raise InputError(f"--ray {address}: cannot connect to Ray ({' '.join(str(exc).split())})") from None
    return ray, True


def check_reachable(address: str, timeout: float = 5.0) -> None:
    """Raise a one-line :class:`InputError` when nothing answers at a ``host:port`` or
    ``ray://host:port`` address (Ray itself keeps retrying an unreachable one for minutes).
    Addresses of other forms are left to Ray."""
    import socket  # noqa: PLC0415
    from urllib.parse import urlsplit  # noqa: PLC0415

    from gtvo.errors import InputError  # noqa: PLC0415

    try:
        parts = urlsplit(address if "://" in address else f"tcp://{address}")
        host, port = parts.hostname, parts.port
    except ValueError:
        return
    if not host or port is None:
        return
    try:
        socket.create_connection((host, port), timeout=timeout).close()
    except OSError as exc:
        raise InputError(f"--ray {address}: nothing answers at {host}:{port} ({exc.strerror or exc})") from None


def run_on_ray(jobs: list[dict[str, Any]], on_done: OnDone) -> None:
    """Run ``jobs`` as Ray tasks (one CPU each) on the Ray this process is connected to
    (:func:`start_ray`).

    The workers must see the logs' and the output folder's paths (a shared file system) and
    import the same gtvo (Ray puts the driver's ``sys.path`` on theirs; on other machines gtvo
    must be installed there). Their environment is :data:`WORKER_ENV` (Ray's ``runtime_env``).
    """
    import ray  # noqa: PLC0415

    refs: dict[Any, int] = {}
    try:
        task = ray.remote(run_log).options(num_cpus=1, max_retries=0, runtime_env={"env_vars": dict(WORKER_ENV)})
        refs = {task.remote(job): i for i, job in enumerate(jobs)}
        pending = list(refs)
        while pending:
            ready, pending = ray.wait(pending, num_returns=1)
            for ref in ready:
                try:
                    result = ray.get(ref)
                except Exception as exc:  # noqa: BLE001 - a worker that died, a task Ray could not run
                    result = failure(exc)
                on_done(refs[ref], result)
    except BaseException:
        for ref in refs:
            try:
                ray.cancel(ref, force=True)
            except Exception:  # noqa: BLE001,S110 - finished already
                pass
        raise
