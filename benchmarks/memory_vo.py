"""Memory and speed of a long run: does anything pile up frame after frame?

    python benchmarks/memory_vo.py [--sequence DIR] [--frames N] [--solvers handrolled,gtsam] [--every K]
    python benchmarks/memory_vo.py --synthetic 1000 [--solvers gtsam] [--every 50] [--json OUT]

The snippet is played back and forth (frames 0..50, 49..0, 1..50, ...: a continuous path that
reverses at each end, timestamps 0.1 s apart) for ``--frames`` frames through one
``VisualOdometry`` in window mode, and every ``--every`` frames the process's resident memory
(RSS, from /proc/self/statm) and the mean time per frame since the last line are printed. A run
whose memory keeps growing with the frames holds something it should have released (until the
third session every Python factor with its images stayed alive through a reference cycle with
GTSAM: +11 MB per frame with the hand-rolled tracker, +20 MB with GTSAM's). The reversals also
exercise the tracker's recovery: the constant-velocity guess is 2.4 m off there.

``--synthetic N`` runs the N frames of ``gtvo synthetic --frames N`` (the synthetic stereo
sequence, 320x240, 0.15 m per frame forward, docs/synthetic.md) instead, rendered one at a time as
the run asks for them (none preloaded), through the default configuration (``--solvers default``)
or the given solvers. After the table it prints the peak RSS (``ru_maxrss``) and the slope of RSS
over the run's second half (least squares over the samples there, MiB per 100 frames): flat
memory is a slope near 0 (issue 24, item 5).
"""

from __future__ import annotations

import argparse
import dataclasses
import gc
import resource
import sys
import time
from pathlib import Path
from typing import Any, Callable, Iterator

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks.vo_bench import KITTI_SEQUENCE_1, gtvo_config, load_frames  # noqa: E402
from gtvo.config import OdometryConfig  # noqa: E402
from gtvo.datasets import open_sequence  # noqa: E402
from gtvo.datasets.sequence import Frame  # noqa: E402
from gtvo.core.atomic import write_json  # noqa: E402
from gtvo.odometry import VisualOdometry  # noqa: E402


def rss_mb() -> float:
    """Resident set size of this process in MiB (Linux)."""
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * 4096 / 2 ** 20


def ping_pong(n_source: int, n_frames: int) -> list[int]:
    """Source indices 0, 1, ..., n-1, n-2, ..., 0, 1, ... (``n_frames`` of them)."""
    order: list[int] = []
    i, step = 0, 1
    while len(order) < n_frames:
        order.append(i)
        if not 0 <= i + step < n_source:
            step = -step
        i += step
    return order


def peak_rss_mb() -> float:
    """Peak resident set size of this process in MiB since the start or the last :func:`reset_peak_rss`
    (``VmHWM`` of /proc/self/status; ``ru_maxrss``, the whole life's, where that is missing)."""
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1]) / 1024.0
    except OSError:
        pass
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def reset_peak_rss() -> bool:
    """Start :func:`peak_rss_mb` afresh (Linux: ``5`` into /proc/self/clear_refs); False when refused."""
    try:
        with open("/proc/self/clear_refs", "w") as f:
            f.write("5")
        return True
    except OSError:
        return False


def second_half_slope(samples: list[tuple[int, float]]) -> float | None:
    """Least-squares slope of RSS (MiB) against frames over the samples of the second half of the
    run, in MiB per 100 frames (None with fewer than 2 samples there)."""
    if not samples:
        return None
    half = samples[-1][0] / 2.0
    pts = [(f, m) for f, m in samples if f >= half]
    if len(pts) < 2:
        return None
    f, m = np.array(pts, dtype=float).T
    return 100.0 * float(np.polyfit(f, m, 1)[0])


def run_memory(camera: Any, frames: Iterator[Frame], n_frames: int, config: OdometryConfig, every: int,
               label: str, on_row: Callable[[str], None] = print) -> dict[str, Any]:
    """Feed ``frames`` to one ``VisualOdometry``; RSS and ms/frame every ``every`` frames (a table row each)."""
    gc.collect()
    vo = VisualOdometry(camera, config)
    samples: list[tuple[int, float]] = []
    busy = 0.0
    for k, frame in enumerate(frames):
        t0 = time.perf_counter()
        vo.process(frame)
        busy += time.perf_counter() - t0
        if (k + 1) % every == 0 or k + 1 == n_frames:
            n = (k % every) + 1
            samples.append((k + 1, rss_mb()))
            on_row(f"| {label} | {k + 1} | {samples[-1][1]:.0f} | {1000.0 * busy / n:.0f} | {len(vo.keyframes)} | "
                   f"{vo.failures} |")
            busy = 0.0
    out = {"label": label, "samples": samples, "slope_mib_per_100_frames": second_half_slope(samples),
           "keyframes": len(vo.keyframes), "failures": vo.failures}
    del vo
    return out


def synthetic_main(args: argparse.Namespace) -> int:
    """The ``--synthetic N`` run: frames rendered as asked for, RSS table, peak and second-half slope."""
    from gtvo.datasets.synthetic import make_synthetic_sequence  # noqa: PLC0415

    seq = make_synthetic_sequence(n_frames=args.synthetic)  # gtvo synthetic --frames N's sequence
    print(f"synthetic sequence, {len(seq)} frames ({seq.camera.left.width}x{seq.camera.left.height}) rendered one "
          f"at a time; RSS before the run: {rss_mb():.0f} MiB\n")
    print("| solver | frames | RSS (MiB) | ms/frame (last block, odometry only) | keyframes | failures |")
    print("|---|---|---|---|---|---|")
    runs = []
    for solver in [s.strip() for s in args.solvers.split(",") if s.strip()]:
        config = OdometryConfig() if solver == "default" else gtvo_config(solver, "window")
        frames = (seq.frame(i) for i in range(len(seq)))
        fresh = reset_peak_rss()  # the scene's set-up peaks above the run: not counted
        runs.append(run_memory(seq.camera, frames, len(seq), config, args.every, solver))
        runs[-1]["peak_rss_mib"] = peak_rss_mb()
        runs[-1]["peak_since"] = "run start" if fresh else "process start"
    for r in runs:
        rss = [m for _, m in r["samples"]]
        print(f"\n{r['label']}: RSS {rss[0]:.0f} MiB at frame {r['samples'][0][0]}, {rss[-1]:.0f} MiB at frame "
              f"{r['samples'][-1][0]}, peak {r['peak_rss_mib']:.0f} MiB (since the {r['peak_since']}); slope over the "
              f"second half {r['slope_mib_per_100_frames']:+.2f} MiB per 100 frames")
    if args.json is not None:
        write_json(args.json, {"frames": len(seq), "runs": runs})
    return 0


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sequence", type=Path, default=KITTI_SEQUENCE_1, metavar="DIR")
    ap.add_argument("--frames", type=int, default=300)
    ap.add_argument("--solvers", default="handrolled,gtsam")
    ap.add_argument("--every", type=int, default=50)
    ap.add_argument("--synthetic", type=int, default=None, metavar="N",
                    help="run the N frames of `gtvo synthetic --frames N` instead (solvers: 'default' = OdometryConfig())")
    ap.add_argument("--json", type=Path, default=None, metavar="OUT", help="--synthetic: also write the figures as JSON")
    args = ap.parse_args(argv)
    if args.synthetic is not None:
        if args.synthetic < 2 or args.every < 1:
            print(f"error: --synthetic must be >= 2 and --every >= 1, got {args.synthetic} and {args.every}",
                  file=sys.stderr)
            return 2
        return synthetic_main(args)
    seq = open_sequence(args.sequence)
    source = load_frames(seq, progress=False)
    order = ping_pong(len(source), args.frames)
    print(f"{seq.name}: {len(source)} frames played back and forth, {args.frames} frames per run; "
          f"RSS with the frames loaded: {rss_mb():.0f} MiB\n")
    print("| solver | frames | RSS (MiB) | ms/frame (last block) | keyframes | failures |")
    print("|---|---|---|---|---|---|")
    for solver in [s.strip() for s in args.solvers.split(",") if s.strip()]:
        gc.collect()
        vo = VisualOdometry(seq.camera, gtvo_config(solver, "window"))
        t_block = time.perf_counter()
        for k, i in enumerate(order):
            vo.process(dataclasses.replace(source[i], index=k, timestamp=0.1 * k))
            if (k + 1) % args.every == 0 or k + 1 == len(order):
                n = (k % args.every) + 1
                ms = 1000.0 * (time.perf_counter() - t_block) / n
                print(f"| {solver} | {k + 1} | {rss_mb():.0f} | {ms:.0f} | {len(vo.keyframes)} | {vo.failures} |",
                      flush=True)
                t_block = time.perf_counter()
        del vo
    return 0


if __name__ == "__main__":
    sys.exit(main())
