"""The whole-log refinement (issue 32): refined against window-only, in one run per log.

For each log the VO runs once (``gtvo run``'s defaults with ``refine.enabled``, so that the window
keeps its keyframes); then, as ``gtvo run`` does:
* without loop closing: the window's trajectory (``--no-refine``) against the refined one
  (:func:`gtvo.refinement.run.refine_run`: every keyframe refined, the other frames re-placed);
* with loop closing (``--loop-closure``; synthetic loops): the loop closing's answer of today (the
  loop-closed keyframe pose graph, then its frames re-placed) against the refined one (the graph
  started from the loop-closed keyframes, with the accepted loop edges in it).
Printed per log: frames, keyframes, ATE before / after (SE(3) and Sim(3) alignment, m), their
ratio, the Sim(3) scale before / after, the window pass's seconds and the refinement's (graph
and frame re-placement) and their ratio, and the refinement's iterations and loop edges.

Logs: KITTI_sequence_1, the KITTI raw drive 0001 (no ground truth here: only its path length and
times), TUM fr3/teddy's first 20 frames, the EuRoC V1_01 clip, synthetic sequences without loops
(forward, turn) and synthetic loops (several seeds, 300+ frames), rendered in memory.

``--scaling [N,...]``: the refinement's time against the number of keyframes (synthetic loop,
every frame a keyframe at its true pose with stereo points and its own compact images, as the
window keeps them; default 100 to 2000 keyframes, each size in its own process), the share of
GTSAM's Values copies, the covariances' time, peak memory, and the figure docs/refinement_scaling.png.

Usage: python benchmarks/refine.py [--quick] [--only NAME,...] [--scaling [N,...] [--stack S]]
"""

from __future__ import annotations

import copy
import resource
import sys
import time
from pathlib import Path

import numpy as np

from gtvo.config import OdometryConfig
from gtvo.datasets import open_sequence
from gtvo.datasets.synthetic import make_synthetic_sequence
from gtvo.evaluation.accuracy import run_accuracy
from gtvo.loops.closing import close_loops_of_run, refine_result_frames
from gtvo.pipeline import run_odometry
from gtvo.refinement import RefineConfig
from gtvo.refinement.run import refine_run
from loop_closure_synthetic import DATA  # noqa: E402 (the shared data folder; run from benchmarks/)


REAL = {"kitti": DATA / "kitti_stereo_sample" / "KITTI_sequence_1",
        "raw": DATA / "kitti_raw_2011_09_26_drive_0001_stereo",
        "tum": DATA / "rgbd_dataset_freiburg3_teddy_first20",
        "euroc": DATA / "euroc_v101_static_stereo"}
#: synthetic logs: (name, motion, seed, frames, image noise, loop closing)
SYNTHETIC = [("forward s1", "forward", 1, 300, 1.0, False), ("turn s2", "turn", 2, 300, 1.0, False),
             ("loop s1", "loop", 1, 300, 0.0, True), ("loop s2", "loop", 2, 300, 2.0, True),
             ("loop s3", "loop", 3, 320, 1.0, True), ("loop s4", "loop", 4, 300, 1.0, True),
             ("loop s5", "loop", 5, 300, 1.0, True)]


def measure(seq, loops: bool, config: RefineConfig | None = None) -> dict:
    """One window pass, then the window's (or loop closing's) answer and the refined one."""
    cfg = OdometryConfig(refine=config or RefineConfig(enabled=True))
    t0 = time.perf_counter()
    _, odo = run_odometry(seq, cfg)
    t_window = time.perf_counter() - t0
    traj, kfs, indices, covs = odo.trajectory, odo.keyframe_positions, odo.frame_indices, odo.link_covariances
    points, mask = odo.keyframe_points, odo.tracked
    res = before = None
    if loops:
        res = close_loops_of_run(seq, traj, indices, kfs, odometry_covariances=covs, keyframe_points=points,
                                 tracking_config=cfg.tracking, refine_frames=False, refine=mask,
                                 photometric=cfg.photometric)
        before = copy.deepcopy(res)
        refine_result_frames(seq, before, indices, kfs, False, covs, points, cfg.tracking, mask,
                             photometric=cfg.photometric)
    t0 = time.perf_counter()
    out = refine_run(seq, odo, res)
    t_refine = time.perf_counter() - t0
    old = before.trajectory if loops else traj
    new = res.trajectory if loops else out.trajectory
    row = {"frames": len(traj), "keyframes": len(kfs), "t_window": t_window, "t_refine": t_refine,
           "summary": out.summary, "path_before": _path(old.poses), "path_after": _path(new.poses)}
    if seq.has_ground_truth:
        row["before"], row["after"] = run_accuracy(seq, old), run_accuracy(seq, new)
    return row


def _path(poses: np.ndarray) -> float:
    return float(np.linalg.norm(np.diff(poses[:, :3, 3], axis=0), axis=1).sum())


def _fmt(name: str, m: dict) -> str:
    s = m["summary"]
    t = f"{m['t_window']:.0f} | {m['t_refine']:.1f} | {m['t_refine'] / m['t_window']:.2f}"
    extra = f"{s['iterations']} | {s['loop_edges']} / {s['loop_edges_dropped']} | {s['ran']}"
    if "before" not in m:
        return (f"| {name} | {m['frames']} / {m['keyframes']} | path {m['path_before']:.2f} -> {m['path_after']:.2f} m "
                f"| | | | | {t} | {extra} |")
    b, a = m["before"], m["after"]
    return (f"| {name} | {m['frames']} / {m['keyframes']} | {b['ate_rmse_m']:.4f} -> {a['ate_rmse_m']:.4f} "
            f"| **{a['ate_rmse_m'] / b['ate_rmse_m']:.3f}** | {b['ate_sim3_rmse_m']:.4f} -> {a['ate_sim3_rmse_m']:.4f} "
            f"| {a['ate_sim3_rmse_m'] / b['ate_sim3_rmse_m']:.3f} | {b['scale_ratio']:.4f} -> {a['scale_ratio']:.4f} "
            f"| {t} | {extra} |")


HEADER = ("| log | frames / keyframes | ATE SE(3) before -> after [m] | ratio | ATE Sim(3) before -> after [m] "
          "| ratio | scale before -> after | window s | refine s | ratio | iterations | loop edges / dropped | kept |\n"
          "|---|---|---|---|---|---|---|---|---|---|---|---|---|")


def accuracy(only: set[str] | None, quick: bool) -> None:
    print(HEADER, flush=True)
    for name, path in REAL.items():
        if only and name not in only:
            continue
        if not path.exists():
            print(f"| {name} | missing: {path} |")
            continue
        print(_fmt(name, measure(open_sequence(path), loops=False)), flush=True)
    for name, motion, seed, frames, noise, loops in SYNTHETIC[:3] if quick else SYNTHETIC:
        if only and name.split()[0] not in only and name not in only:
            continue
        seq = make_synthetic_sequence(n_frames=frames, noise_sigma=noise, seed=seed, motion=motion)
        print(_fmt(f"synthetic {name}, {frames} frames" + (" (loop closing)" if loops else ""),
                   measure(seq, loops=loops)), flush=True)


def _stack(argv: list[str]) -> int:
    """``--stack S``: ``refine.stacked_factors`` of the scaling runs (default: the setting's default)."""
    return int(argv[argv.index("--stack") + 1]) if "--stack" in argv else RefineConfig().stacked_factors


def scaling(sizes: list[int], stack: int | None = None) -> None:
    """The refinement's time and memory against the number of keyframes (module docstring): each
    size in its own process (:func:`scaling_one`, its peak memory its own), then the figure."""
    import json  # noqa: PLC0415
    import subprocess  # noqa: PLC0415

    rows = []
    print("| keyframes | host-target pairs | seconds | per keyframe | per iteration | GTSAM's own [s] (share) "
          "| covariances s | hosts keeping Jacobians | image packs per keyframe | RSS before / peak [MB] "
          "| refinement's memory per keyframe [MB] |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for n in sizes:
        out = subprocess.run([sys.executable, __file__, "--scaling-one", str(n), "--stack",
                              str(RefineConfig().stacked_factors if stack is None else stack)], check=True,
                             capture_output=True, text=True).stdout
        r = json.loads(out.strip().splitlines()[-1])
        rows.append((n, r["seconds"], r["seconds_gtsam_own"]))
        per_it = r["seconds_lm"] / max(r["iterations"], 1)
        print(f"| {n} | {r['pairs']} | {r['seconds']:.1f} | {1000 * r['seconds'] / n:.1f} ms | {per_it:.2f} s "
              f"| {r['seconds_gtsam_own']:.1f} s ({100 * r['seconds_gtsam_own'] / r['seconds']:.0f} %) "
              f"| {r['seconds_covariances']:.1f} | {r['hosts_keeping_jacobians']} | {r['image_packs'] / n:.1f} "
              f"| {r['rss_before_mb']:.0f} / {r['peak_mb']:.0f} "
              f"| {(r['peak_mb'] - r['rss_before_mb']) / n:.2f} |", flush=True)
    _scaling_figure(rows)


def scaling_one(n: int, lap: int = 100, stack: int | None = None) -> dict:
    """One size of :func:`scaling`: a synthetic loop of ``lap`` frames (320 x 240) driven round
    again and again, every frame a keyframe at its true pose moved by about 1 mm / 0.5 mrad (so
    that LM has work) with its stereo points and its own images kept as the window keeps a
    keyframe that left it (:class:`factors.compact_image.CompactGradientImage`; the rendered images
    rounded to whole grey levels, as a camera's); the defaults' memory bounds, 3 LM iterations.
    Also the Values copies alone (:func:`values_copy_seconds`)."""
    import gtsam  # noqa: PLC0415

    import factors.smart as smart  # noqa: PLC0415
    from factors.smoothness import ConstantVelocityFactor  # noqa: PLC0415
    import gtvo.window.gtsam_solver as gtsam_solver  # noqa: PLC0415
    from factors.compact_image import SHARED_PACKED_CACHE, CompactGradientImage  # noqa: PLC0415
    from factors.photometric import GradientImage  # noqa: PLC0415
    from gtvo.core.image import to_float_gray  # noqa: PLC0415
    from gtvo.frontend import init_keyframe_points  # noqa: PLC0415
    from gtvo.refinement import RefinementInput, refine_keyframes  # noqa: PLC0415
    from gtvo.window import WindowConfig, WindowKeyframe, WindowMembers, WindowSettings  # noqa: PLC0415

    seq = make_synthetic_sequence(n_frames=lap, motion="loop", seed=1, noise_sigma=1.0)
    frames = []
    for i in range(lap):
        fr = seq.frame(i)
        # whole grey levels, as a camera's 8-bit output (the compact images are then uint8, as KITTI's)
        left, right = (np.clip(np.rint(to_float_gray(im, name)), 0, 255) for im, name in ((fr.left, "left"),
                                                                                        (fr.right, "right")))
        frames.append((GradientImage(left), GradientImage(right), init_keyframe_points(left, right, seq.camera)))
    rng = np.random.default_rng(0)
    kfs = []
    for k in range(n):
        img, right, pts = frames[k % lap]
        T = gtsam.Pose3(seq.gt_poses[k % lap]).retract(np.r_[rng.normal(0, 5e-4, 3), rng.normal(0, 1e-3, 3)])
        kfs.append(WindowKeyframe(k, T if k else gtsam.Pose3(seq.gt_poses[0]), np.zeros(2), CompactGradientImage(img),
                                  pts.pixels, pts.inverse_depth, pts.variance, right=CompactGradientImage(right),
                                  timestamp=0.1 * k))
    del frames
    rss_before = _rss_mb()
    cov_seconds = []
    marginals = gtsam_solver.marginals_of_graph

    def timed_marginals(*args, **kwargs):
        t = time.perf_counter()
        out = marginals(*args, **kwargs)
        cov_seconds.append(time.perf_counter() - t)
        return out

    gtsam_solver.marginals_of_graph = timed_marginals
    # GTSAM's calls of the Python factors (host factors, motion priors; each gets its copy of the
    # Values) and the seconds inside them; the LM loop's seconds: the rest is GTSAM's own (C++)
    calls, inside, lm, cpp = [0], [0.0], [0.0], [0.0]

    def counting(cls):
        evaluate = cls._evaluate

        def counted(self, this, values, H):
            calls[0] += 1
            t = time.perf_counter()
            try:
                return evaluate(self, this, values, H)
            finally:
                inside[0] += time.perf_counter() - t

        cls._evaluate = counted

    counting(smart.HostPointsFactor)
    counting(ConstantVelocityFactor)
    loop = gtsam_solver.optimize_by_iterations

    def timed_loop(*args, **kwargs):
        t, before = time.perf_counter(), inside[0]
        out = loop(*args, **kwargs)
        lm[0] += time.perf_counter() - t
        cpp[0] += time.perf_counter() - t - (inside[0] - before)
        return out

    gtsam_solver.optimize_by_iterations = timed_loop
    hosts, keeping = [], []  # the host factors; after each iteration, how many kept their Jacobians
    made = smart.HostPointsFactor.__init__

    def collect(self, *args, **kwargs):
        made(self, *args, **kwargs)
        hosts.append(self)

    smart.HostPointsFactor.__init__ = collect
    packs = SHARED_PACKED_CACHE.packs
    t0 = time.perf_counter()
    counting = WindowSettings(WindowConfig(), on_iteration=lambda it, cost: keeping.append(
        sum(h._reserved > 0 for h in hosts)))
    res = refine_keyframes(RefinementInput(WindowMembers(seq.pinhole, seq.camera.baseline, kfs), counting),
                           RefineConfig(enabled=True, max_iterations=3, relative_tolerance=0.0,
                                        stacked_factors=RefineConfig().stacked_factors if stack is None else stack))
    sec = time.perf_counter() - t0
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    copy_seconds, copy_calls = values_copy_seconds(n)
    return {"keyframes": n, "pairs": int(round(res.targets_mean * n)), "seconds": sec, "iterations": res.iterations,
            "seconds_covariances": sum(cov_seconds), "seconds_lm": sec - sum(cov_seconds),
            "rss_before_mb": rss_before, "peak_mb": peak, "factor_calls": calls[0],
            "seconds_lm_loop": lm[0], "seconds_gtsam_own": cpp[0],
            "hosts_keeping_jacobians": max(keeping, default=0), "image_packs": SHARED_PACKED_CACHE.packs - packs,
            "copies_seconds": calls[0] * copy_seconds / copy_calls}


def values_copy_seconds(n: int) -> tuple[float, int]:
    """One LM iteration of ``n`` trivial Python factors over a Values of the refinement's shape (a
    pose and an affine per keyframe, the rig offset): ``(seconds, calls)``, the copies of the
    Values GTSAM hands every call of a Python factor (the dependency facts) with nothing else to
    do, and how many calls made them; the whole-log graph has one Python factor per host."""
    import gtsam  # noqa: PLC0415

    from gtvo.core.keys import affine_key, pose_key, rig_offset_key  # noqa: PLC0415

    values = gtsam.Values()
    graph = gtsam.NonlinearFactorGraph()
    noise = gtsam.noiseModel.Unit.Create(1)

    calls = [0]

    def error(this, v, H):
        calls[0] += 1
        if H is not None:
            H[0] = np.zeros((1, 6))
        return np.zeros(1)

    for k in range(n):
        values.insert(pose_key(k), gtsam.Pose3())
        values.insert(affine_key(k), np.zeros(2))
        graph.add(gtsam.CustomFactor(noise, [pose_key(k)], error))
        graph.add(gtsam.PriorFactorPose3(pose_key(k), gtsam.Pose3(), gtsam.noiseModel.Unit.Create(6)))
        graph.add(gtsam.PriorFactorVector(affine_key(k), np.zeros(2), gtsam.noiseModel.Unit.Create(2)))
    values.insert(rig_offset_key(), np.zeros(2))
    graph.add(gtsam.PriorFactorVector(rig_offset_key(), np.zeros(2), gtsam.noiseModel.Unit.Create(2)))
    opt = gtsam.LevenbergMarquardtOptimizer(graph, values, gtsam.LevenbergMarquardtParams())
    t0 = time.perf_counter()
    opt.iterate()
    return time.perf_counter() - t0, calls[0]


def _rss_mb() -> float:
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
    return float("nan")


def _scaling_figure(rows: list[tuple[int, float, float]]) -> None:
    import matplotlib  # noqa: PLC0415

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415

    n, sec, own = np.array(rows, dtype=float).T
    fig, ax = plt.subplots(figsize=(5, 3.4))
    ax.plot(n, sec, "o-", label="measured (3 LM iterations)")
    ax.plot(n, own, "s:", label="of it GTSAM's own (Values copies)")
    ax.plot(n, sec[0] / n[0] * n, "--", color="gray", label="linear through the first point")
    ax.set_xlabel("keyframes")
    ax.set_ylabel("refinement seconds")
    ax.legend()
    ax.grid(alpha=0.3)
    fig.tight_layout()
    out = Path(__file__).resolve().parents[1] / "docs" / "refinement_scaling.png"
    fig.savefig(out, dpi=100)
    print(f"figure: {out}")


def main(argv: list[str]) -> None:
    only = None
    if "--only" in argv:
        only = set(argv[argv.index("--only") + 1].split(","))
    if "--scaling-one" in argv:
        import json  # noqa: PLC0415

        print(json.dumps(scaling_one(int(argv[argv.index("--scaling-one") + 1]), stack=_stack(argv))))
        return
    if "--scaling" in argv:
        i = argv.index("--scaling")
        sizes = [int(x) for x in argv[i + 1].split(",")] if i + 1 < len(argv) and argv[i + 1][0].isdigit() else \
            [100, 250, 500, 1000, 2000]
        scaling(sizes, _stack(argv))
        return
    accuracy(only, "--quick" in argv)
    print(f"peak memory {resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024:.0f} MB")


if __name__ == "__main__":
    main(sys.argv[1:])
