"""Where a frame's time goes (issue 24): milliseconds per frame by stage of one gtvo run.

    python benchmarks/frame_budget.py [--sequence DIR] [--mode window|track] [--solver gtsam|handrolled]
                                      [--frame-step N] [--max-frames N] [--repeat N] [--json OUT]
    python benchmarks/frame_budget.py --points 300,600,1200,2000 [...]   # scaling with the point budget
    python benchmarks/frame_budget.py --overhead [...]                  # the timing's own cost

The default run is ``gtvo run``'s: ``OdometryConfig()`` (window mode, GTSAM window solver) on the
preloaded frames of KITTI_sequence_1 (images decoded before the clock starts). ``--solver`` sets
the tracker's and the window's solver together, as the CLI's ``--solver``. Every run starts from a
fresh ``VisualOdometry`` after one warm-up run on the first frames (numba's compiled kernels
loaded), and the stages are the library's own always-on clock (``VisualOdometry.clock``,
:mod:`gtvo.core.timing`; what each stage covers: docs/evaluation.md, "Where a frame's time goes").
With ``--repeat N`` every figure is the median over N runs (each stage's median on its own, so the
stages' sum may differ a little from the frame's median). "opened per frame": how often the stage
was entered from outside itself (``linearisation``: a host factor's evaluation by GTSAM, or a
``HostPoints`` call from a solver), from the first run. "frames by kind": how many frames ran a
window optimisation, made a keyframe without one (the first frame; ``WindowConfig.optimize_every``)
or were only tracked, and their mean ms (first run): what a keyframe rule that takes fewer frames
would save.

The machine may be shared: each run also times one OpenCV StereoSGBM on the first frame
(``benchmarks.vo_bench.reference_ms``), and the tables give times as multiples of that reference
("x ref", each run's times over the mean of the reference timed just before and just after it)
beside the milliseconds, with the load average at the start and the end. Compare runs through
the ratios. ``--cpu`` times this process's CPU time instead of wall time (the stages, the frame
and the reference alike): other jobs disturb it less. It counts every thread's time: with worker
threads (the window's thread pool of main 0cf6c65, ``--threads``) it is the work done, not the
time waited (a stage is charged the CPU time of all threads while the main thread is in it), and
reading the process's CPU clock costs a few microseconds per stage then.

``--points`` runs the window with each point budget (``frontend.points_per_keyframe``) and fits
``ms/frame = a + b * points`` (the points each keyframe kept after the stereo search, mean over
keyframes) for the frame (also in multiples of the reference, which takes the machine's load
out) and each stage: ``max rel. residual`` is the largest ``|measured - fit| / measured`` over
the budgets (linear when small). ``--overhead`` alternates
runs with the clock on and off (``VisualOdometry.clock = None``) and prints the ratio of the
median frame times.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks.vo_bench import KITTI_SEQUENCE_1, fmt, load_frames, markdown_table, reference_ms, score  # noqa: E402
from gtvo.config import OdometryConfig, SolverConfig  # noqa: E402
from gtvo.core.timing import FRAME_STAGES, StageClock  # noqa: E402
from gtvo.datasets import open_sequence  # noqa: E402
from gtvo.errors import InputError  # noqa: E402
from gtvo.core.atomic import write_json  # noqa: E402
from gtvo.odometry import VisualOdometry  # noqa: E402

#: frames of the warm-up run (compiled kernels loaded; the window fills and marginalises once)
WARMUP_FRAMES = 10


def make_config(mode: str, solver: str | None, points: int | None = None,
                threads: int | None = None) -> OdometryConfig:
    """``OdometryConfig()`` with ``mode``, the CLI's ``--solver`` (None: the defaults), a point
    budget and the window's threads (``WindowConfig.threads``; None: the default)."""
    kwargs: dict[str, Any] = {"mode": mode}
    if solver is not None:
        kwargs["solver"] = SolverConfig.both(solver)
    if points is not None:
        kwargs["points_per_keyframe"] = points
    config = OdometryConfig(**kwargs)
    if threads is not None:
        if not hasattr(config.window, "threads"):
            raise InputError("--threads: this gtvo's WindowConfig has no 'threads' setting")
        config = dataclasses.replace(config, window=dataclasses.replace(config.window, threads=threads))
    return config


def run_once(camera: Any, frames: list, config: OdometryConfig, timed: bool = True,
             cpu: bool = False) -> dict[str, Any]:
    """One run over ``frames``: ms per frame (wall, or with ``cpu`` this process's CPU time), by
    stage too, counters and the trajectory."""
    timer = time.process_time if cpu else time.perf_counter
    vo = VisualOdometry(camera, config)
    vo.clock = StageClock(timer=timer) if timed else None
    kinds: dict[str, list[float]] = {}  # frame kind -> ms of each such frame
    t0 = timer()
    for f in frames:
        t_frame, n_kf, n_win = timer(), len(vo.keyframes), len(vo.window_results)
        vo.process(f)
        kind = ("window optimised" if len(vo.window_results) > n_win else
                "keyframe, no optimisation" if len(vo.keyframes) > n_kf else "tracked only")
        kinds.setdefault(kind, []).append(1000.0 * (timer() - t_frame))
    vo.finish()  # the keyframes still waiting for the window (WindowConfig.optimize_every > 1)
    seconds = timer() - t0
    n = len(frames)
    stages = {k: 1000.0 * v / n for k, v in vo.clock.snapshot().items()}
    calls = {} if vo.clock is None else {k: c / n for k, c in vo.clock.entries.items()}
    iterations = [r.iterations for r in vo.window_results]
    return {"frame_ms": 1000.0 * seconds / n, "stage_ms": stages, "keyframes": len(vo.keyframes),
            "window_optimisations": len(vo.window_results), "failures": vo.failures,
            "window_iterations_mean": float(np.mean(iterations)) if iterations else None,
            "points_per_keyframe": float(np.mean([len(kf.points) for kf in vo.keyframes])),
            "stage_calls_per_frame": calls, "stage_entries_per_frame": sum(calls.values()),
            "frame_kinds_ms": {k: [len(v), float(np.mean(v))] for k, v in kinds.items()},
            "trajectory": vo.trajectory("gtvo")}


def hook_cost_us(cpu: bool = False, n: int = 20000) -> float:
    """Wall microseconds of one stage opened and closed inside another (the hooks' own cost), with
    the CPU-time timer when ``cpu``."""
    clock = StageClock(timer=time.process_time if cpu else time.perf_counter)
    with clock.activate("other"):
        t0 = time.perf_counter()
        for _ in range(n):
            clock.leave(clock.enter("linearisation"))
        return 1e6 * (time.perf_counter() - t0) / n


def reference_cpu_ms(frames: list, repeats: int = 5) -> float:
    """:func:`benchmarks.vo_bench.reference_ms` in this process's CPU time (all threads'): median ms."""
    return reference_ms(frames, repeats, timer=time.process_time)


def measure(camera: Any, frames: list, config: OdometryConfig, repeat: int, cpu: bool = False) -> dict[str, Any]:
    """``repeat`` runs, the reference timed before each and after the last (a run's reference: the
    mean of the two around it); medians of the times and of the ratios, the first run's rest."""
    reference = reference_cpu_ms if cpu else reference_ms
    runs, refs = [], [reference(frames)]
    for _ in range(repeat):
        runs.append(run_once(camera, frames, config, cpu=cpu))
        refs.append(reference(frames))
    around = [0.5 * (refs[i] + refs[i + 1]) for i in range(repeat)]
    out = dict(runs[0])
    out["frame_ms"] = statistics.median(r["frame_ms"] for r in runs)
    out["stage_ms"] = {k: statistics.median(r["stage_ms"][k] for r in runs) for k in runs[0]["stage_ms"]}
    out["reference_ms"] = statistics.median(around)
    out["frame_x_ref"] = statistics.median(r["frame_ms"] / a for r, a in zip(runs, around))
    out["stage_x_ref"] = {k: statistics.median(r["stage_ms"][k] / a for r, a in zip(runs, around))
                          for k in runs[0]["stage_ms"]}
    out["frame_ms_runs"] = [r["frame_ms"] for r in runs]
    out["clock"] = "cpu" if cpu else "wall"
    return out


def machine() -> dict[str, Any]:
    """Load average, cores and the code's commit (the context of the figures)."""
    try:
        commit = subprocess.run(["git", "-C", str(Path(__file__).resolve().parents[1]), "rev-parse", "--short", "HEAD"],
                                capture_output=True, text=True, timeout=10).stdout.strip() or None
    except (OSError, subprocess.SubprocessError):
        commit = None
    return {"load_average_1_5_15": [round(x, 2) for x in os.getloadavg()], "cpus": os.cpu_count(), "commit": commit}


def budget_table(res: dict[str, Any]) -> str:
    """stage | ms per frame | % of frame | x ref | opened per frame, then the frame's total."""
    frame = res["frame_ms"]
    rows = []
    for name in FRAME_STAGES:
        ms = res["stage_ms"].get(name, 0.0)
        if name in ("reading", "outputs") and ms == 0.0:
            continue  # not part of a run on preloaded frames
        calls = res["stage_calls_per_frame"].get(name, 0.0)
        rows.append([name, f"{ms:.1f}", f"{100.0 * ms / frame:.1f} %", f"{res['stage_x_ref'].get(name, 0.0):.2f}",
                     f"{calls:.1f}"])
    staged = sum(res["stage_ms"].values())
    rows.append([f"**frame** ({res['clock']})", f"**{frame:.1f}**", "100 %", f"**{res['frame_x_ref']:.2f}**", ""])
    rows.append(["(stages' sum)", f"{staged:.1f}", f"{100.0 * staged / frame:.1f} %",
                 f"{sum(res['stage_x_ref'].values()):.2f}", ""])
    return markdown_table(["stage", "ms per frame", "% of frame", "x ref", "opened per frame"], rows)


def linear_fit(x: list[float], y: list[float]) -> dict[str, float]:
    """Least-squares ``y = a + b x``: slope per 100 x, intercept, R^2 and the largest relative residual."""
    X, Y = np.asarray(x, dtype=float), np.asarray(y, dtype=float)
    b, a = np.polyfit(X, Y, 1)
    pred = a + b * X
    ss = float(np.sum((Y - Y.mean()) ** 2))
    r2 = 1.0 - float(np.sum((Y - pred) ** 2)) / ss if ss > 0 else 1.0
    rel = np.abs(Y - pred) / np.maximum(np.abs(Y), 1e-9)
    return {"per_100_points": 100.0 * float(b), "intercept": float(a), "r2": r2, "max_rel_residual": float(rel.max())}


def point_budgets(text: str) -> list[int]:
    """``--points``' budgets: at least 3 whole numbers, comma-separated."""
    try:
        budgets = [int(p) for p in text.split(",") if p.strip()]
    except ValueError:
        raise InputError(f"--points takes whole numbers separated by commas, got {text!r}") from None
    if len(budgets) < 3:
        raise InputError(f"--points needs at least 3 budgets to test a line, got {text!r}")
    return budgets


def scaling(camera: Any, frames: list, args: argparse.Namespace) -> dict[str, Any]:
    """The window with each point budget of ``--points``: ms per frame and by stage, and linear fits."""
    budgets = point_budgets(args.points)
    rows = {p: measure(camera, frames, make_config(args.mode, args.solver, p, args.threads), args.repeat, args.cpu)
            for p in budgets}
    x = [rows[p]["points_per_keyframe"] for p in budgets]
    cols = ["frame x ref", "frame"] + [s for s in FRAME_STAGES
                                       if any(rows[p]["stage_ms"].get(s, 0.0) > 0 for p in budgets)]

    def value(p: int, c: str) -> float:
        if c == "frame x ref":
            return rows[p]["frame_x_ref"]
        return rows[p]["frame_ms"] if c == "frame" else rows[p]["stage_ms"].get(c, 0.0)

    fits = {c: linear_fit(x, [value(p, c) for p in budgets]) for c in cols}
    header = ["points (budget / kept)", "keyframes", "window iterations", "ref ms"] + \
        [c if c == "frame x ref" else f"{c} ms" for c in cols]
    table = [[f"{p} / {rows[p]['points_per_keyframe']:.0f}", str(rows[p]["keyframes"]),
              fmt(rows[p]["window_iterations_mean"], ".2f"), f"{rows[p]['reference_ms']:.1f}"]
             + [f"{value(p, c):.2f}" if c == "frame x ref" else f"{value(p, c):.1f}" for c in cols] for p in budgets]
    fit_rows = [("fit: per 100 points", "per_100_points", "{:.2f}"), ("fit: intercept", "intercept", "{:.1f}"),
                ("fit: R^2", "r2", "{:.3f}"), ("fit: max rel. residual", "max_rel_residual", "{:.1%}")]
    for label, key, spec in fit_rows:
        table.append([label, "", "", ""] + [spec.format(fits[c][key]) for c in cols])
    print(markdown_table(header, table))
    return {"budgets": budgets, "points_kept": x, "fits": fits,
            "runs": {str(p): {k: v for k, v in rows[p].items() if k != "trajectory"} for p in budgets}}


def overhead(camera: Any, frames: list, config: OdometryConfig, repeat: int) -> dict[str, Any]:
    """Runs with the clock on and off, alternating; the ratio of the median frame times."""
    on, off = [], []
    for _ in range(max(repeat, 3)):
        on.append(run_once(camera, frames, config, timed=True)["frame_ms"])
        off.append(run_once(camera, frames, config, timed=False)["frame_ms"])
    ratio = statistics.median(on) / statistics.median(off)
    print(f"clock on: {statistics.median(on):.1f} ms/frame (runs {', '.join(f'{t:.1f}' for t in on)}); "
          f"clock off: {statistics.median(off):.1f} ms/frame (runs {', '.join(f'{t:.1f}' for t in off)}); "
          f"on / off = {ratio:.3f}")
    return {"on_ms": on, "off_ms": off, "ratio": ratio}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sequence", type=Path, default=KITTI_SEQUENCE_1, metavar="DIR")
    ap.add_argument("--mode", choices=("window", "track"), default="window")
    ap.add_argument("--solver", choices=("gtsam", "handrolled"), default=None,
                    help="tracker and window solver, as gtvo run --solver (default: the library's defaults)")
    ap.add_argument("--frame-step", type=int, default=1, help="use every N-th frame (default 1)")
    ap.add_argument("--max-frames", type=int, default=None)
    ap.add_argument("--repeat", type=int, default=1, help="runs per figure; the median is printed (default 1)")
    ap.add_argument("--points", default=None, metavar="P1,P2,...", help="scaling mode: these point budgets")
    ap.add_argument("--overhead", action="store_true", help="compare runs with the stage clock on and off")
    ap.add_argument("--cpu", action="store_true",
                    help="time this process's CPU time instead of wall time (the reference too): less disturbed "
                         "by other jobs on a shared machine")
    ap.add_argument("--threads", type=int, default=None, metavar="N",
                    help="the window's threads (WindowConfig.threads; default: the configuration's)")
    ap.add_argument("--json", type=Path, default=None, metavar="OUT", help="also write the figures as JSON")
    args = ap.parse_args(argv)
    try:
        if args.repeat < 1 or args.frame_step < 1:
            raise InputError(f"--repeat and --frame-step must be >= 1, got {args.repeat} and {args.frame_step}")
        if args.points is not None:
            point_budgets(args.points)
        if args.json is not None and not args.json.resolve().parent.is_dir():
            raise InputError("the folder of --json does not exist", path=args.json)
        seq = open_sequence(args.sequence, max_frames=args.max_frames).subsampled(args.frame_step)
        frames = load_frames(seq, progress=False)
        config = make_config(args.mode, args.solver, threads=args.threads)
    except InputError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    start = machine()
    run_once(seq.camera, frames[:WARMUP_FRAMES], config)  # warm-up: compiled kernels loaded
    what = (f"{seq.name}, {len(frames)} frames (frame step {args.frame_step}), mode {config.mode}, tracker solver "
            f"{config.solver.tracker}, window solver {config.solver.window}, window threads "
            f"{getattr(config.window, 'threads', '-')}, {args.repeat} run(s) per figure")
    print(f"# gtvo frame budget: {what}\n\nload average at start {start['load_average_1_5_15']} on "
          f"{start['cpus']} cores, commit {start['commit']}\n")
    out: dict[str, Any] = {"what": what, "machine_start": start}
    if args.points:
        out["scaling"] = scaling(seq.camera, frames, args)
    elif args.overhead:
        out["overhead"] = overhead(seq.camera, frames, config, args.repeat)
    else:
        res = measure(seq.camera, frames, config, args.repeat, args.cpu)
        acc = score(res["trajectory"], seq)
        print(budget_table(res))
        print(f"\n({res['clock']} time{' of all threads' if args.cpu else ''}; x ref: over one OpenCV StereoSGBM of frame 0 timed just before and after each "
              "run; 'opened per frame': entries of the stage from outside itself; what each stage covers: "
              "docs/evaluation.md, \"Where a frame's time goes\")")
        cost = hook_cost_us(args.cpu)
        print(f"\n{1000.0 / res['frame_ms']:.1f} frames/s ({res['frame_ms']:.1f} ms/frame; runs "
              f"{', '.join(f'{t:.1f}' for t in res['frame_ms_runs'])}; {res['clock']} time); reference (one SGBM) "
              f"{res['reference_ms']:.1f} ms: frame = {res['frame_x_ref']:.2f} x ref\n"
              f"keyframes {res['keyframes']} of {len(frames)}, window optimisations {res['window_optimisations']}, "
              f"tracking failures {res['failures']}, points per keyframe {res['points_per_keyframe']:.0f}\n"
              f"frames by kind (first run; count, mean ms): "
              f"{'; '.join(f'{k} {n}, {ms:.1f}' for k, (n, ms) in res['frame_kinds_ms'].items())}\n"
              f"ATE {fmt(acc['ate_m'], '.4f')} m (SE(3)), segment drift {fmt(acc['seg_t_pct'], '.2f')} %\n"
              f"timing hooks: {res['stage_entries_per_frame']:.0f} stages opened per frame x {cost:.2f} us = "
              f"{res['stage_entries_per_frame'] * cost / 1000.0:.3f} ms per frame "
              f"({0.1 * res['stage_entries_per_frame'] * cost / res['frame_ms']:.2f} % of the frame)")
        out["budget"] = {k: v for k, v in res.items() if k != "trajectory"} | {"accuracy": acc,
                                                                              "hook_cost_us": cost}
    out["machine_end"] = machine()
    print(f"\nload average at the end {out['machine_end']['load_average_1_5_15']}")
    if args.json is not None:
        write_json(args.json, out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
