"""Overhead per log of `gtvo batch` on the local process pool and on a local Ray (issue 23).

Writes tiny synthetic logs, runs batches of S and L of them with ``gtvo.batch`` on each runner
and prints, per runner and number of workers W, the batches' wall times and

    overhead per log = ((wall_L - wall_S) x W - (runs_L - runs_S)) / (L - S)
    fixed overhead   = wall_S - (runs_S + S x overhead per log) / W

``runs`` is the sum of the logs' own seconds (report.json). The per-log figure is the
core-seconds per log spent outside the odometry (handing the log to a worker, opening it,
writing its outputs (plots, point cloud), the Sim(3) ATE, its summary row); the fixed figure is
what a batch costs once (starting the workers, which import gtvo; a local Ray's start; the
summary). On a shared machine the figures move from run to run; compare the runners' ratios,
measured back to back. Needs Ray for the Ray rows (``pip install "gtvo[ray]"``).

    PYTHONPATH=. python benchmarks/batch_overhead.py --logs 2 6 --repeats 2
"""

from __future__ import annotations

import argparse
import importlib.util
import os
import statistics
import tempfile
import time
from pathlib import Path

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import gtvo  # noqa: E402
from gtvo.datasets.synthetic import make_synthetic_sequence, write_sequence_kitti  # noqa: E402


def make_logs(root: Path, n: int, frames: int) -> Path:
    """``n`` tiny logs (160x120, seeds 1..n) in ``root/logs``."""
    logs = root / "logs"
    for seed in range(1, n + 1):
        write_sequence_kitti(make_synthetic_sequence(n_frames=frames, width=160, height=120, seed=seed),
                             logs / f"log{seed}")
    return logs


def measure(logs: Path, out: Path, workers: int, ray: str | None) -> dict[str, float]:
    """One batch: its wall time and the sum of its runs' seconds."""
    t0 = time.perf_counter()
    res = gtvo.batch(logs, out, jobs=workers, ray=ray, progress=False)
    wall = time.perf_counter() - t0
    if res.failed:
        raise SystemExit(f"logs failed: {res.failed}")
    return {"wall": wall, "runs": sum(r["seconds"] for r in res.rows)}


def ray_start_seconds(cpus: int) -> float:
    """Seconds to start and stop a local Ray of ``cpus`` CPUs (no dashboard)."""
    import logging

    import ray

    t0 = time.perf_counter()
    ray.init(num_cpus=cpus, include_dashboard=False, logging_level=logging.WARNING)
    ray.shutdown()
    return time.perf_counter() - t0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--logs", type=int, nargs=2, default=[2, 6], metavar=("S", "L"),
                    help="sizes of the small and the large batch (default 2 6)")
    ap.add_argument("--frames", type=int, default=6, help="frames per log (default 6)")
    ap.add_argument("--repeats", type=int, default=2, help="batches per case; the median is used")
    ap.add_argument("--workers", type=int, nargs="+", default=[1, 2], help="numbers of workers (default 1 2)")
    args = ap.parse_args()
    small, large = args.logs
    runners: list[str | None] = [None, "local"]
    if importlib.util.find_spec("ray") is None:
        print("Ray not installed: process pool only")
        runners = [None]
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        sets = {n: make_logs(root / f"set{n}", n, args.frames) for n in (small, large)}
        gtvo.batch(sets[small], root / "warm", jobs=1, progress=False)  # numba's cache filled
        print(f"batches of {small} and {large} logs x {args.frames} frames (160x120), median of {args.repeats}; "
              f"cores: {os.cpu_count()}")
        print(f"{'runner':<10} {'W':>2} {'wall S s':>9} {'wall L s':>9} {'runs L s':>9} {'per log s':>10} "
              f"{'fixed s':>8}")
        per_log: dict[tuple[str, int], float] = {}
        walls: dict[tuple[str, int], float] = {}
        for workers in args.workers:
            for ray in runners:
                med = {}
                for n in (small, large):
                    ms = [measure(sets[n], root / f"out_{ray}_{workers}_{n}_{k}", workers, ray)
                          for k in range(args.repeats)]
                    med[n] = {key: statistics.median(m[key] for m in ms) for key in ms[0]}
                S, L = med[small], med[large]
                one = ((L["wall"] - S["wall"]) * workers - (L["runs"] - S["runs"])) / (large - small)
                fixed = S["wall"] - (S["runs"] + small * one) / workers
                name = "pool" if ray is None else "ray local"
                per_log[(name, workers)] = one
                walls[(name, workers)] = L["wall"]
                print(f"{name:<10} {workers:>2} {S['wall']:>9.2f} {L['wall']:>9.2f} {L['runs']:>9.2f} {one:>10.2f} "
                      f"{fixed:>8.2f}")
        if "local" in runners:
            for workers in args.workers:
                ray_one, pool_one = per_log[("ray local", workers)], per_log[("pool", workers)]
                ratio = f"{ray_one / pool_one:.2f}x" if ray_one > 0 and pool_one > 0 else "n/a (a slope below the noise)"
                print(f"overhead per log, ray local / pool, {workers} worker(s): {ratio}; wall time of {large} logs, "
                      f"ray local / pool: {walls[('ray local', workers)] / walls[('pool', workers)]:.2f}x")
            starts = [ray_start_seconds(2) for _ in range(args.repeats)]
            print(f"local Ray start + shutdown (2 CPUs), alone: {statistics.median(starts):.2f} s")


if __name__ == "__main__":
    main()
