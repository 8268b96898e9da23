"""The window beside the tracker: ``window.parallel`` against the sequential order, in one run.

    python benchmarks/parallel_window.py [--repeat 3] [--steps 1,2,3] [--modes M,..] [--logs] [--json OUT]
    python benchmarks/parallel_window.py --starts 0,1,2,3,5,8      # ATE from other first frames
    python benchmarks/parallel_window.py --solve 10                # one window, one and two kernel threads

On the preloaded frames of KITTI_sequence_1 at every ``--steps`` frame step, runs ``gtvo run``'s
default configuration (window mode) in each of :data:`MODES`: ``parallel+threads`` (the window's
worker with two kernel threads, ``window.worker_threads: 2``), ``parallel`` (the worker on one
thread), ``auto`` (the default: the schedule decides whether and when the window moves to the
worker) and ``sequential`` (``window.parallel: false``), alternating
(parallel+threads, parallel, auto, sequential, parallel+threads, ...), ``--repeat`` times each, each from a fresh
``VisualOdometry`` after one warm-up run of each mode (compiled kernels loaded). A parallel run's
clock starts once its worker process has answered (its start-up, timed apart, is excluded as the
front end's imports are; ``auto`` starts its worker during the run, which counts); it ends after
``vo.finish()``. Per mode: frames/s (median), CPU seconds
per frame (this process's, plus the worker's: the work done on both cores), the worker's peak
resident memory and its shared image buffers, the bound the CPU split puts on the parallel
run's speed-up on two idle cores (the sequential run's CPU per frame over the busiest thread's:
the front end, or the worker's main thread, i.e. its CPU less what its pool thread ran beside it),
ATE (SE(3)) and scale (path length over the ground
truth's), tracking failures, and whether every repeat gave the same trajectory bytes. ``--logs``
adds every other shared log (KITTI raw, EuRoC, TUM RGB-D: 60 frames each) once per mode, for
tracking failures. ``--starts`` runs KITTI_sequence_1 at every frame from each given first frame
once per mode and prints the ATEs and their ratio (how much of an ATE difference is the start's
chance). ``--solve`` solves one KITTI window with one and two kernel threads (:func:`solve_by_threads`).
The load average (``uptime``) is printed at the start and the end: on a shared
machine only the ratios of one run mean anything.
"""

from __future__ import annotations

import argparse
import dataclasses
import hashlib
import os
import resource
import statistics
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks.vo_bench import KITTI_SEQUENCE_1, SHARED_DATA, fmt, load_frames, markdown_table, score  # noqa: E402
from gtvo.config import OdometryConfig  # noqa: E402
from gtvo.core.atomic import write_json  # noqa: E402
from gtvo.datasets import open_sequence  # noqa: E402
from gtvo.evaluation.trajectory import Trajectory  # noqa: E402
from gtvo.odometry import VisualOdometry  # noqa: E402
from gtvo.odometry.window_worker import SLOTS, WindowWorker  # noqa: E402

OTHER_LOGS = {"KITTI raw 0001": SHARED_DATA / "kitti_raw_2011_09_26_drive_0001_stereo",
              "EuRoC V1_01 static": SHARED_DATA / "euroc_v101_static_stereo",
              "TUM fr3 teddy (RGB-D)": SHARED_DATA / "rgbd_dataset_freiburg3_teddy_first20"}


#: The modes compared, each ``(window.parallel, window.worker_threads)``: the worker with its two
#: kernel threads (``gtvo run``'s parallel window), the worker on one thread, the sequential order.
#: ``auto`` (the default): the schedule moves the window to the worker at its decision keyframe
#: where keyframes overlap (its start-up CPU then counts in the run's).
MODES: dict[str, tuple[bool | str, int | None]] = {"parallel+threads": (True, 2), "parallel": (True, 1),
                                                   "auto": ("auto", None), "sequential": (False, None)}


def config_for(mode: str) -> OdometryConfig:
    """``gtvo run``'s default configuration with ``window.parallel`` and ``window.worker_threads`` of ``mode``."""
    parallel, threads = MODES[mode]
    base = OdometryConfig()
    return dataclasses.replace(base, window=dataclasses.replace(base.window, parallel=parallel,
                                                                worker_threads=threads))


def one_run(seq: Any, frames: list, mode: str) -> dict[str, Any]:
    """One timed run over ``frames`` in ``mode`` (:data:`MODES`); the figures of the module docstring."""
    t_start = time.perf_counter()
    vo = VisualOdometry(seq.camera, config_for(mode))
    worker = vo.window if isinstance(vo.window, WindowWorker) else None
    try:
        started = worker.worker_usage() if worker is not None else None  # the worker is up: its start-up CPU
        startup = time.perf_counter() - t_start
        cpu0, t0 = time.process_time(), time.perf_counter()
        for f in frames:
            vo.process(f)
        vo.finish()
        wall = time.perf_counter() - t0
        cpu = time.process_time() - cpu0
        if worker is None and isinstance(vo.window, WindowWorker):  # auto moved it during the run
            worker = vo.window
        usage = worker.worker_usage() if worker is not None else None
    finally:
        vo.close()
    est = vo.trajectory("gtvo")
    poses = np.stack([e.T_world_cam for e in vo.estimates])
    n = len(frames)
    out = {"frames": n, "wall_s": wall, "fps": n / wall, "cpu_ms_per_frame": 1000 * cpu / n,
           "worker_cpu_ms_per_frame": None, "pool_cpu_ms_per_frame": None, "worker_rss_mib": None, "startup_s": startup,
           "failures": vo.failures, "lost": vo.lost_frames, "keyframes": len(vo.keyframes),
           "optimisations": len(vo.window_results), "sha": hashlib.sha256(poses.tobytes()).hexdigest()[:16]}
    if usage is not None:
        start_cpu, start_pool = (0.0, 0.0) if started is None else (started.cpu_seconds, started.pool_cpu_seconds)
        out["worker_cpu_ms_per_frame"] = 1000 * (usage.cpu_seconds - start_cpu) / n
        out["pool_cpu_ms_per_frame"] = 1000 * (usage.pool_cpu_seconds - start_pool) / n
        out["worker_rss_mib"] = usage.max_rss_mib
        out["cpu_ms_per_frame"] += out["worker_cpu_ms_per_frame"]
        out["wait_ms_per_frame"] = 1000 * vo.clock.seconds.get("window_wait", 0.0) / n
    out.update(score(Trajectory(est.timestamps, est.poses, "gtvo"), seq))
    return out


def compare(name: str, seq: Any, repeat: int, modes: list[str]) -> list[dict[str, Any]]:
    """Alternate the runs of ``modes`` on ``seq`` (the sequential one last); one summary row per mode,
    the parallel ones with their ratios to the sequential row."""
    frames = load_frames(seq, progress=False)
    for mode in modes:  # warm-up: kernels loaded in this process and on disk
        one_run(seq, frames[:10], mode)
    runs: dict[str, list[dict[str, Any]]] = {mode: [] for mode in modes}
    for _ in range(repeat):
        for mode in modes:
            runs[mode].append(one_run(seq, frames, mode))
    rows = []
    for mode in modes:
        rs = runs[mode]
        med = {k: statistics.median(r[k] for r in rs) for k in ("fps", "cpu_ms_per_frame", "wall_s")}
        first = rs[0]
        rows.append({"log": name, "mode": mode, "runs": len(rs),
                     "fps": med["fps"], "fps_runs": [r["fps"] for r in rs], "cpu_ms_per_frame": med["cpu_ms_per_frame"],
                     "worker_cpu_ms_per_frame": first["worker_cpu_ms_per_frame"],
                     "pool_cpu_ms_per_frame": first.get("pool_cpu_ms_per_frame"),
                     "wait_ms_per_frame": first.get("wait_ms_per_frame"),
                     "worker_rss_mib": first["worker_rss_mib"], "startup_s": first["startup_s"],
                     "ate_m": first["ate_m"], "scale": first["scale"], "seg_t_pct": first["seg_t_pct"],
                     "failures": first["failures"], "lost": first["lost"], "keyframes": first["keyframes"],
                     "optimisations": first["optimisations"],
                     "identical": len({r["sha"] for r in rs}) == 1, "sha": first["sha"]})
    seqr = rows[-1]
    for par in rows[:-1]:
        par["fps_ratio"] = par["fps"] / seqr["fps"]
        par["cpu_ratio"] = par["cpu_ms_per_frame"] / seqr["cpu_ms_per_frame"]
        par["ate_ratio"] = (par["ate_m"] / seqr["ate_m"]) if par["ate_m"] and seqr["ate_m"] else None
        # on two idle cores the busier thread's CPU per frame bounds the run: the front end's, or the
        # worker's main thread's (its CPU less what its pool thread ran beside it)
        worker = par["worker_cpu_ms_per_frame"] or 0.0
        main = worker - (par["pool_cpu_ms_per_frame"] or 0.0)
        par["cpu_bound_ratio"] = seqr["cpu_ms_per_frame"] / max(main, par["cpu_ms_per_frame"] - worker)
    return rows


def ate_by_start(starts: list[int]) -> int:
    """ATE (SE(3)) of both modes from each first frame of KITTI_sequence_1, and their ratio."""
    full = open_sequence(KITTI_SEQUENCE_1)
    rows = []
    for start in starts:
        seq = full._select(list(range(start, len(full))))
        frames = load_frames(seq, progress=False)
        ate = [one_run(seq, frames, mode)["ate_m"] for mode in ("sequential", "parallel+threads")]
        rows.append([str(start), fmt(ate[0], ".4f"), fmt(ate[1], ".4f"), fmt(ate[1] / ate[0], ".3f")])
    print(markdown_table(["first frame", "sequential ATE m", "parallel ATE m", "parallel x sequential"], rows))
    return 0


def solve_by_threads(repeat: int) -> int:
    """One KITTI window (the first of 7 keyframes of a sequential run of KITTI_sequence_1) solved by
    ``solve_gtsam`` with one and with two kernel threads in this process, alternating, ``repeat``
    times each: wall and main-thread CPU (min and median), the pool thread's CPU, and whether the
    results are the same bytes. The main thread's CPU is what bounds the worker on two idle cores;
    CPU figures are much less disturbed by a loaded machine than wall time."""
    import copy  # noqa: PLC0415

    import gtvo.window.optimizer as window_optimizer  # noqa: PLC0415
    from gtvo.core import kernel_threads  # noqa: PLC0415

    captured: list[tuple[tuple, dict]] = []
    solve = window_optimizer.solve_gtsam

    def capture(*args: Any, **kwargs: Any) -> Any:
        if not captured and len(args[0].keyframes) >= 7:
            captured.append(copy.deepcopy((args, kwargs)))
        return solve(*args, **kwargs)

    window_optimizer.solve_gtsam = capture
    try:
        seq = open_sequence(KITTI_SEQUENCE_1)
        vo = VisualOdometry(seq.camera, config_for("sequential"))
        for f in load_frames(seq.truncated(14), progress=False):
            vo.process(f)
    finally:
        window_optimizer.solve_gtsam = solve
    figures: dict[int, list[tuple[float, float, float, bytes]]] = {1: [], 2: []}
    for _ in range(repeat):
        for threads in (1, 2):
            kernel_threads.set_kernel_threads(threads)
            args, kwargs = copy.deepcopy(captured[0])
            pool0, cpu0, t0 = kernel_threads.pool_cpu_seconds(), time.thread_time(), time.perf_counter()
            result = solve(*args, **kwargs)
            wall, cpu = time.perf_counter() - t0, time.thread_time() - cpu0
            poses = np.stack([np.asarray(kf.pose.matrix()) for kf in args[0].keyframes])
            figures[threads].append((wall, cpu, kernel_threads.pool_cpu_seconds() - pool0,
                                     poses.tobytes() + np.float64(result.cost).tobytes()))
    kernel_threads.set_kernel_threads(1)
    rows = []
    for threads, fs in figures.items():
        wall, cpu, pool = (np.array([f[k] for f in fs]) * 1000 for k in range(3))
        rows.append([str(threads), f"{wall.min():.1f} / {np.median(wall):.1f}", f"{cpu.min():.1f} / {np.median(cpu):.1f}",
                     f"{np.median(pool):.1f}", f"{np.median(cpu + pool):.1f}"])
    n_points = sum(len(kf) for kf in captured[0][0][2])
    print(f"# one KITTI window ({len(captured[0][0][2])} keyframes, {n_points} points), {repeat} solves per thread count")
    print(markdown_table(["kernel threads", "wall ms min / median", "main-thread CPU ms min / median",
                          "pool-thread CPU ms (median)", "CPU ms, both (median)"], rows))
    same = len({f[3] for fs in figures.values() for f in fs}) == 1
    print(f"same bytes for every solve and thread count: {'yes' if same else 'NO'}")
    return 0


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--steps", default="1,2,3", help="frame steps of KITTI_sequence_1 (comma-separated)")
    ap.add_argument("--logs", action="store_true", help="also every other shared log, once per mode")
    ap.add_argument("--starts", default=None, help="first frames of KITTI_sequence_1 (comma-separated): ATE only")
    ap.add_argument("--modes", default=",".join(MODES),
                    help=f"modes to alternate, the sequential one last (comma-separated, of {', '.join(MODES)})")
    ap.add_argument("--solve", type=int, default=None, metavar="REPEAT",
                    help="only: one KITTI window solved with one and two kernel threads, REPEAT times each")
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args(argv)
    if args.solve:
        return solve_by_threads(args.solve)
    if args.starts:
        return ate_by_start([int(s) for s in args.starts.split(",")])
    modes = [m for m in args.modes.split(",") if m]
    if not modes or modes[-1] != "sequential" or any(m not in MODES for m in modes):
        print(f"--modes: give modes of {', '.join(MODES)}, the sequential one last; got {args.modes!r}", file=sys.stderr)
        return 2
    print(f"# parallel window: load average at start {os.getloadavg()} on {os.cpu_count()} cores")
    rows: list[dict[str, Any]] = []
    for step in [int(s) for s in args.steps.split(",") if s]:
        seq = open_sequence(KITTI_SEQUENCE_1).subsampled(step)
        rows += compare(f"KITTI_sequence_1 step {step}", seq, args.repeat, modes)
    if args.logs:
        for name, path in OTHER_LOGS.items():
            if path.is_dir():
                rows += compare(name, open_sequence(path, max_frames=60), 1, modes)
    header = ["log", "mode", "frames/s (median)", "x sequential", "bound x seq. (CPU split)",
              "CPU ms/frame (both processes)", "CPU x seq.", "worker CPU ms/frame (its pool thread's)",
              "front end waited ms/frame", "worker RSS MiB", "ATE m", "ATE x seq.", "scale", "seg t %",
              "failures", "optimisations", "same bytes every run"]
    table = [[r["log"], r["mode"], fmt(r["fps"], ".2f"), fmt(r.get("fps_ratio"), ".2f"), fmt(r.get("cpu_bound_ratio"), ".2f"),
              fmt(r["cpu_ms_per_frame"], ".1f"), fmt(r.get("cpu_ratio"), ".2f"),
              "-" if r["worker_cpu_ms_per_frame"] is None else
              f"{r['worker_cpu_ms_per_frame']:.1f} ({r['pool_cpu_ms_per_frame'] or 0.0:.1f})",
              fmt(r.get("wait_ms_per_frame"), ".1f"),
              fmt(r["worker_rss_mib"], ".0f"), fmt(r["ate_m"], ".4f"), fmt(r.get("ate_ratio"), ".3f"),
              fmt(r["scale"], ".4f"), fmt(r["seg_t_pct"], ".2f"), str(r["failures"]), str(r["optimisations"]),
              "yes" if r["identical"] else "NO"] for r in rows]
    print(markdown_table(header, table))
    by_log: dict[str, dict[str, str]] = {}
    for r in rows:
        by_log.setdefault(r["log"], {})[r["mode"]] = r["sha"]
    same = [log for log, shas in by_log.items() if len(shas) > 1 and
            len({sha for mode, sha in shas.items() if mode != "sequential"}) == 1]
    print(f"\nparallel modes with the same trajectory bytes as each other: {len(same)} of {len(by_log)} logs")
    print(f"\nshared image buffers: {SLOTS} slots of the left and right images (KITTI 1241x376: "
          f"{SLOTS * 2 * 1241 * 376 * 4 / 2**20:.1f} MiB); this process's peak RSS "
          f"{resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024:.0f} MiB; worker start-up "
          f"{statistics.median(r['startup_s'] for r in rows if r['mode'] != 'sequential'):.2f} s (median, excluded)")
    print(f"load average at the end {os.getloadavg()}")
    if args.json is not None:
        write_json(args.json, {"rows": rows, "load_end": os.getloadavg()})
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
