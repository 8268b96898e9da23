"""Why the whole-log refinement gains little over the loop-closed pose graph (issue 32): the same
graph solved from the truth, and with its parts taken out, on the keyframes of synthetic loops.

Per log: one window pass and loop closing (``gtvo run --loop-closure``'s defaults, as
``benchmarks/refine.py``), then :func:`gtvo.refinement.refine_keyframes` on the window's keyframes in
several variants. Scored on the keyframes alone (no frame re-placement): SE(3) ATE against their
ground truth (and its ratio to the loop-closed keyframe pose graph's), the Sim(3) alignment's scale.

Variants: the window's keyframes; the loop-closed pose graph; the refinement's defaults (from the
loop-closed poses); its loop term in parts (the loop edges' ``BetweenFactorPose3`` without the
photometric loop pairs; the pairs without the factor, whose information is made negligible); the
window edges off; the ``space`` candidates; and the oracles: the same graph (same factors, same
targets, 20 iterations) started from the ground-truth keyframe poses, and from them with the true
depths of every keyframe's points (``SyntheticSequence.true_depth``). If the graph's optimum from
the truth is near the pose graph's ATE, the limit is the model (factors, noise, candidates), not
the optimiser or its start.

``--plot``: the error of every keyframe along the log (window, pose graph, refinement, oracle),
one panel per log, to docs/refinement_error_along_log.png.

``--supersample N``: the synthetic images rendered with N x N rays per pixel (area-integrated pixels,
as a sensor's; docs/benchmarks.md "Longer logs and area-integrated pixels").

``--oracles-only``: only the two oracles (with the window's and the pose graph's rows; not with
``--plot``). ``--interpolation spline``: the factors' kernel samples the cubic B-spline instead
(``scale_bias.use_spline_kernel``; docs/refinement.md, "The model's scale bias"). ``--cache DIR``:
the window pass pickled there and read back on the next run. The last column: the local scale error,
the relative error of the distance between keyframes 10 apart, over the log.

Usage: python benchmarks/refine_oracle.py [--seeds 1,2,3,4,5] [--motion loop] [--supersample N] [--plot]
       [--oracles-only] [--cache DIR] [--interpolation spline]
"""

from __future__ import annotations

import contextlib
import dataclasses
import pickle
import sys
import time
from pathlib import Path
from typing import Iterator

import numpy as np

import gtvo.refinement.solve as refinement_solve
from gtvo.config import OdometryConfig
from gtvo.datasets.synthetic import SyntheticSequence, make_synthetic_sequence
from gtvo.evaluation.alignment import umeyama_alignment
from gtvo.loops.closing import close_loops_of_run, odometry_covariances
from gtvo.loops.closure_graph import LoopEdge
from gtvo.pipeline import TRACKED_OUTCOMES, process_sequence
from gtvo.refinement import RefineConfig, RefinementInput, refine_keyframes
from gtvo.window import WindowKeyframe, WindowMembers, WindowSettings

#: seed -> (frames, image noise): seeds 1-3 are benchmarks/refine.py's loops, 4 and 5 held out
LOOPS = {1: (300, 0.0), 2: (300, 2.0), 3: (320, 1.0), 4: (300, 1.0), 5: (300, 1.0)}
#: information of a loop edge kept only for the photometric loop pairs it brings (no pull)
NEGLIGIBLE = 1e-12


@dataclasses.dataclass
class WindowPass:
    """One run's window pass and loop closing, what the variants share."""

    seq: SyntheticSequence
    config: OdometryConfig
    keyframes: list[WindowKeyframe]
    covariances: list
    loop_closed: dict[int, np.ndarray]
    edges: list[LoopEdge]
    rig_offset: np.ndarray | None


def window_pass(seq: SyntheticSequence) -> WindowPass:
    cfg = OdometryConfig(refine=RefineConfig(enabled=True))
    vo, traj, _ = process_sequence(seq, cfg)
    kfs = [p for p, e in enumerate(vo.estimates) if e.is_keyframe]
    covs = odometry_covariances(vo.estimates, kfs)
    res = close_loops_of_run(seq, traj, [e.index for e in vo.estimates], kfs, odometry_covariances=covs,
                             keyframe_points={kf.index: kf.points for kf in vo.keyframes},
                             tracking_config=cfg.tracking, refine_frames=False,
                             refine=[e.outcome in TRACKED_OUTCOMES for e in vo.estimates], photometric=cfg.photometric)
    edges = [e for e, a in zip(res.measured_edges, res.accepted) if a]
    rig = vo.window.rig
    return WindowPass(seq, cfg, vo.window.every_keyframe(), covs, res.keyframe_poses, edges,
                      None if rig is None else rig.solved_offset)


def window_pass_cached(seq: SyntheticSequence, key: str, argv: list[str]) -> WindowPass:
    """:func:`window_pass`, kept in ``--cache DIR`` (pickled) when given: the oracles of two versions
    of the factors then start from the same keyframes and points."""
    if "--cache" not in argv:
        return window_pass(seq)
    path = Path(argv[argv.index("--cache") + 1]) / f"window_pass-{key}.pkl"
    if path.exists():
        with open(path, "rb") as fh:
            run = pickle.load(fh)
        run.seq = seq
        return run
    run = window_pass(seq)
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "wb") as fh:
        pickle.dump(dataclasses.replace(run, seq=None), fh)
    return run


def keyframe_errors(seq: SyntheticSequence, poses: dict[int, np.ndarray]) -> tuple[np.ndarray, float]:
    """Per keyframe (by frame index), its position error after the SE(3) alignment; the Sim(3) scale."""
    idx = sorted(poses)
    est = np.array([np.asarray(poses[i])[:3, 3] for i in idx])
    gt = np.array([seq.gt_poses[i][:3, 3] for i in idx])
    err = np.linalg.norm(umeyama_alignment(est, gt).apply(est) - gt, axis=1)
    return err, float(umeyama_alignment(est, gt, with_scale=True).scale)


def local_scale_errors(seq: SyntheticSequence, poses: dict[int, np.ndarray], span: int = 10) -> np.ndarray:
    """Per keyframe ``i``, the relative error of the distance from keyframe ``i`` to keyframe ``i + span``
    (the local scale over about 50 frames; no alignment needed)."""
    idx = sorted(poses)
    est = np.array([np.asarray(poses[i])[:3, 3] for i in idx])
    gt = np.array([seq.gt_poses[i][:3, 3] for i in idx])
    return np.linalg.norm(est[span:] - est[:-span], axis=1) / np.linalg.norm(gt[span:] - gt[:-span], axis=1) - 1.0


def true_depths(seq: SyntheticSequence, keyframes: list[WindowKeyframe]) -> list[WindowKeyframe]:
    """Copies of the keyframes with their points' true inverse depths (nearest pixel)."""
    out = []
    for kf in keyframes:
        z = seq.true_depth(kf.index)
        u = np.clip(np.rint(kf.pixels[:, 0]).astype(int), 0, z.shape[1] - 1)
        v = np.clip(np.rint(kf.pixels[:, 1]).astype(int), 0, z.shape[0] - 1)
        out.append(dataclasses.replace(kf, inverse_depth=(1.0 / z[v, u]).astype(kf.inverse_depth.dtype)))
    return out


@contextlib.contextmanager
def without_loop_pairs() -> Iterator[None]:
    """The refinement's targets chosen as if there were no loop edge (its factors stay)."""
    choose = refinement_solve.covisible_targets
    refinement_solve.covisible_targets = lambda *a, **k: choose(*a, **{**k, "loops": []})
    try:
        yield
    finally:
        refinement_solve.covisible_targets = choose


def variants(run: WindowPass, oracles_only: bool = False) -> dict[str, dict[int, np.ndarray]]:
    """Keyframe poses (frame index -> 4x4) of every variant (module docstring); ``oracles_only``:
    the window's, the pose graph's and the two oracles'."""
    seq, wp = run.seq, run
    truth = {kf.index: seq.gt_poses[kf.index] for kf in wp.keyframes}
    weak = [dataclasses.replace(e, information=NEGLIGIBLE * np.eye(6)) for e in wp.edges]

    def refine(config: RefineConfig = RefineConfig(enabled=True), start=wp.loop_closed, edges=wp.edges,
               keyframes=wp.keyframes) -> dict[int, np.ndarray]:
        run = RefinementInput(WindowMembers(seq.pinhole, seq.camera.baseline, keyframes),
                              WindowSettings(wp.config.window, wp.config.photometric), wp.rig_offset,
                              loop_edges=edges, start_poses=start, odometry_covariances=wp.covariances)
        r = refine_keyframes(run, config)
        return {kf.index: kf.pose.matrix() for kf in r.keyframes}

    oracle = RefineConfig(enabled=True, max_iterations=20)
    out = {"window": {kf.index: kf.pose.matrix() for kf in wp.keyframes}, "loop-closed pose graph": wp.loop_closed}
    if oracles_only:
        out["oracle: from the true poses"] = refine(oracle, start=truth)
        out["oracle: true poses and depths"] = refine(oracle, start=truth, keyframes=true_depths(seq, wp.keyframes))
        return out
    out["refined (defaults)"] = refine()
    with without_loop_pairs():
        out["loop edges only (no loop pairs)"] = refine()
    out["photometric loop pairs only"] = refine(edges=weak)
    out["window edges off"] = refine(RefineConfig(enabled=True, window_edges=False))
    out["space candidates"] = refine(RefineConfig(enabled=True, candidates="space"))
    out["oracle: from the true poses"] = refine(oracle, start=truth)
    out["oracle: true poses and depths"] = refine(oracle, start=truth, keyframes=true_depths(seq, wp.keyframes))
    return out


def plot(panels: list[tuple[str, dict[str, np.ndarray]]]) -> None:
    import matplotlib  # noqa: PLC0415

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415

    fig, axes = plt.subplots(len(panels), 1, figsize=(7, 1.9 * len(panels)), sharex=False, squeeze=False)
    for ax, (name, errors) in zip(axes[:, 0], panels):
        for label in ("window", "loop-closed pose graph", "refined (defaults)", "oracle: true poses and depths"):
            ax.plot(1000 * errors[label], label=label, lw=1)
        ax.set_title(name, fontsize=9)
        ax.set_ylabel("error [mm]")
        ax.grid(alpha=0.3)
    axes[0, 0].legend(fontsize=7, ncol=2)
    axes[-1, 0].set_xlabel("keyframe")
    fig.tight_layout()
    out = Path(__file__).resolve().parents[1] / "docs" / "refinement_error_along_log.png"
    fig.savefig(out, dpi=90)
    print(f"figure: {out}")


def main(argv: list[str]) -> None:
    seeds = [int(s) for s in argv[argv.index("--seeds") + 1].split(",")] if "--seeds" in argv else sorted(LOOPS)
    motion = argv[argv.index("--motion") + 1] if "--motion" in argv else "loop"
    supersample = int(argv[argv.index("--supersample") + 1]) if "--supersample" in argv else 1
    oracles_only = "--oracles-only" in argv
    if "--interpolation" in argv and argv[argv.index("--interpolation") + 1] == "spline":
        from scale_bias import use_spline_kernel  # noqa: PLC0415 (run from benchmarks/)
        use_spline_kernel()
    print("| log | variant | keyframe ATE SE(3) [m] | / pose graph | Sim(3) scale | local scale error over 10 keyframes,"
          " mean / RMS / max [%] |\n|---|---|---|---|---|---|")
    panels = []
    for seed in seeds:
        frames, noise = LOOPS.get(seed, (300, 1.0))
        t0 = time.perf_counter()
        seq = make_synthetic_sequence(n_frames=frames, noise_sigma=noise, seed=seed, motion=motion,
                                      supersample=supersample)
        run = window_pass_cached(seq, f"{motion}-{seed}-{frames}-{noise:g}-{supersample}", argv)
        name = f"synthetic {motion} seed {seed}, noise {noise:g}, {frames} frames / {len(run.keyframes)} keyframes"
        errors = {}
        for label, poses in variants(run, oracles_only).items():
            err, scale = keyframe_errors(run.seq, poses)
            local = 100 * local_scale_errors(run.seq, poses)
            errors[label] = err
            ate = float(np.sqrt(np.mean(err ** 2)))
            base = float(np.sqrt(np.mean(errors["loop-closed pose graph"] ** 2))) if len(errors) > 1 else ate
            print(f"| {name} | {label} | {ate:.4f} | {ate / base:.3f} | {scale:.4f} | "
                  f"{np.mean(local):+.3f} / {np.sqrt(np.mean(local ** 2)):.3f} / {np.max(np.abs(local)):.3f} |", flush=True)
        print(f"({name}: {time.perf_counter() - t0:.0f} s)", file=sys.stderr)
        panels.append((name, errors))
    if "--plot" in argv:
        plot(panels)


if __name__ == "__main__":
    main(sys.argv[1:])
