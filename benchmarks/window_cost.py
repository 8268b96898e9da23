"""The sliding window's CPU per frame on a real log, this checkout against another, measured alternately.

    python benchmarks/window_cost.py [--sequence DIR] [--max-frames N] [--frame-step N] [--solver gtsam|handrolled]
    python benchmarks/window_cost.py --compare OTHER_CHECKOUT [--rounds R] [...]

One run: ``OdometryConfig()`` (window mode; ``--solver`` sets the tracker's and the window's) on the
preloaded frames of the log (images decoded before the clock starts), after a warm-up run on its
first frames (numba's compiled kernels loaded), with the library's stage clock reading this
process's CPU time (:class:`gtvo.core.timing.StageClock`, ``timer=time.process_time``). The window's
CPU per frame is the sum of its stages (:data:`WINDOW_STAGES`: the host factors' build, their
residual passes and linearisations, the rest of the solve, marginalisation, covariances); the
frame's is every stage's. The trajectory's SHA-256 says whether two checkouts computed the same
run, to the bit.

``--compare OTHER``: the same run in subprocesses, ``OTHER`` then this checkout, ``--rounds``
times (default 3), so that both see the same machine load; prints each round and the ratios of
the medians (this / other). The machine may be shared: compare ratios measured in one run.
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse  # noqa: E402
import hashlib  # noqa: E402
import json  # noqa: E402
import statistics  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402
from typing import Any  # noqa: E402

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

#: the stage clock's stages that are the window's work (gtvo.core.timing.FRAME_STAGES)
WINDOW_STAGES = ("window_build", "linearisation", "solve", "marginalisation", "covariances")
DEFAULT_SEQUENCE = Path(os.environ.get("GTVO_SHARED_DATA", Path(__file__).resolve().parents[2] / "shared" / "data")
                        ) / "kitti_stereo_sample" / "KITTI_sequence_1"
WARMUP_FRAMES = 8


def measure(sequence: Path, max_frames: int | None, frame_step: int, solver: str | None) -> dict[str, Any]:
    """One warm-up run and one measured run in this process: CPU ms per frame, window and whole."""
    from gtvo.config import OdometryConfig, SolverConfig  # noqa: PLC0415
    from gtvo.core.timing import StageClock  # noqa: PLC0415
    from gtvo.datasets import open_sequence  # noqa: PLC0415
    from gtvo.odometry import VisualOdometry  # noqa: PLC0415

    seq = open_sequence(sequence)
    idx = list(range(0, len(seq), frame_step))
    if max_frames is not None:
        idx = idx[:max_frames]
    frames = [seq.frame(i) for i in idx]
    config = OdometryConfig() if solver is None else OdometryConfig(solver=SolverConfig.both(solver))
    warm = VisualOdometry(seq.camera, config)
    for f in frames[:WARMUP_FRAMES]:
        warm.process(f)
    warm.finish()
    vo = VisualOdometry(seq.camera, config)
    vo.clock = StageClock(timer=time.process_time)
    t0 = time.process_time()
    for f in frames:
        vo.process(f)
    vo.finish()
    total = time.process_time() - t0
    n = len(frames)
    stages = {k: 1000.0 * v / n for k, v in vo.clock.snapshot().items()}
    digest = hashlib.sha256(np.ascontiguousarray(np.stack([e.T_world_cam for e in vo.estimates])).tobytes()).hexdigest()[:16]
    return {"frames": n, "frame_ms": 1000.0 * total / n, "window_ms": sum(stages.get(s, 0.0) for s in WINDOW_STAGES),
            "stage_ms": stages, "window_optimisations": len(vo.window_results),
            "iterations": float(np.mean([r.iterations for r in vo.window_results])) if vo.window_results else 0.0,
            "failures": vo.failures, "trajectory_sha256": digest}


def _child_args(args: argparse.Namespace) -> list[str]:
    out = ["--sequence", str(args.sequence), "--frame-step", str(args.frame_step), "--json-stdout"]
    if args.max_frames is not None:
        out += ["--max-frames", str(args.max_frames)]
    if args.solver is not None:
        out += ["--solver", args.solver]
    return out


def _run_child(checkout: Path, args: argparse.Namespace) -> dict[str, Any]:
    env = dict(os.environ, PYTHONPATH=str(checkout))
    # the checkout's own copy: this file puts its own checkout first on sys.path
    script = checkout.resolve() / "benchmarks" / "window_cost.py"
    out = subprocess.run([sys.executable, str(script)] + _child_args(args), env=env, cwd=str(checkout),
                         capture_output=True, text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--sequence", type=Path, default=DEFAULT_SEQUENCE, metavar="DIR")
    ap.add_argument("--max-frames", type=int, default=None)
    ap.add_argument("--frame-step", type=int, default=1)
    ap.add_argument("--solver", choices=("gtsam", "handrolled"), default=None)
    ap.add_argument("--compare", type=Path, default=None, metavar="OTHER_CHECKOUT")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--json-stdout", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if not args.sequence.is_dir():
        print(f"window_cost: no log folder {args.sequence}", file=sys.stderr)
        return 2
    if args.json_stdout:
        print(json.dumps(measure(args.sequence, args.max_frames, args.frame_step, args.solver)))
        return 0
    if args.compare is None:
        r = measure(args.sequence, args.max_frames, args.frame_step, args.solver)
        print(json.dumps(r, indent=1))
        return 0
    here = Path(__file__).resolve().parents[1]
    rows: dict[str, list[dict[str, Any]]] = {"other": [], "this": []}
    for k in range(args.rounds):
        for name, checkout in (("other", args.compare), ("this", here)):
            r = _run_child(checkout, args)
            rows[name].append(r)
            print(f"round {k + 1} {name:5s}: window {r['window_ms']:7.1f} ms/frame, frame {r['frame_ms']:7.1f} "
                  f"ms/frame, {r['window_optimisations']} optimisations, {r['iterations']:.2f} it, "
                  f"failures {r['failures']}, trajectory {r['trajectory_sha256']}", flush=True)
    med = {name: {key: statistics.median(r[key] for r in rs) for key in ("window_ms", "frame_ms")}
           for name, rs in rows.items()}
    print(f"{args.sequence.name}: window CPU per frame {med['other']['window_ms']:.1f} -> {med['this']['window_ms']:.1f} "
          f"ms (x{med['this']['window_ms'] / med['other']['window_ms']:.2f}); whole frame "
          f"{med['other']['frame_ms']:.1f} -> {med['this']['frame_ms']:.1f} ms "
          f"(x{med['this']['frame_ms'] / med['other']['frame_ms']:.2f}); same trajectory: "
          f"{rows['this'][0]['trajectory_sha256'] == rows['other'][0]['trajectory_sha256']}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
