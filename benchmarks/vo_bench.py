"""Shared pieces of the VO benchmarks (``kitti_vo.py``, ``motion_model_vo.py``): run gtvo on
preloaded frames with per-frame timing, score a trajectory against ground truth, a reference
timing, and markdown tables.

Scores (``gtvo.evaluation.metrics``, on the frames that have a ground-truth pose):

* ``ate_m``: ATE RMSE after SE(3) (Umeyama) alignment, metres;
* ``ate_sim3_m``: ATE RMSE after Sim(3) alignment (the shape: a wrong scale does not count);
* ``scale``: estimated / ground-truth path length (1 when the stereo baseline sets the scale right);
* ``drift_pct``: final position error after aligning the first pose, % of the GT path length
  (None when the GT path is shorter than :data:`MIN_DRIFT_PATH_M`: a static clip has no drift %);
* ``rpe_t_m``, ``rpe_r_deg``: RPE RMSE over 1-frame pairs, translation (m) and rotation (deg);
* ``seg_t_pct``, ``seg_r_deg_per_100m``: the KITTI devkit's segment errors
  (:func:`gtvo.evaluation.metrics.kitti_segment_errors`) over the short lengths :data:`SEGMENT_LENGTHS_M`
  from every frame: the drift measured from every start, not from frame 0 only (None when no
  segment fits);
* ``max_disp_m``: the largest distance of an estimated camera position from the first one (the
  figure for a static clip, where it must stay below 1 cm).
"""

from __future__ import annotations

import dataclasses
import os
import re
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

REPO_ROOT = Path(__file__).resolve().parents[1]
if str(REPO_ROOT) not in sys.path:  # run as `python benchmarks/<script>.py`
    sys.path.insert(0, str(REPO_ROOT))

from benchmarks.peers import make_sgbm  # noqa: E402
from gtvo.errors import InputError  # noqa: E402
from gtvo.core.image import to_uint8  # noqa: E402
from gtvo.evaluation.metrics import ate, drift_percent, kitti_segment_errors, rpe  # noqa: E402
from gtvo.evaluation.accuracy import MIN_DRIFT_PATH_M  # noqa: E402
from gtvo.datasets.sequence import Frame, Sequence  # noqa: E402
from gtvo.evaluation.trajectory import Trajectory  # noqa: E402

#: Segment lengths (m) of the short-snippet KITTI segment metric (the devkit's are 100..800 m).
SEGMENT_LENGTHS_M = (10.0, 20.0, 30.0, 40.0)
#: The real data: ``$GTVO_SHARED_DATA`` or ``../shared/data`` beside the checkout (as tests/conftest.py).
SHARED_DATA = Path(os.environ.get("GTVO_SHARED_DATA") or REPO_ROOT.parent / "shared" / "data")
KITTI_SEQUENCE_1 = SHARED_DATA / "kitti_stereo_sample" / "KITTI_sequence_1"


class ModeUnavailable(Exception):
    """The installed gtvo has no such mode (yet)."""


def gtvo_config(solver: str, mode: str = "track", **overrides: Any):
    """An ``OdometryConfig`` for ``solver`` and ``mode``.

    ``solver`` is the tracker's and the window's solver, as the CLI's ``--solver``
    (``SolverConfig.both(solver)``); ``"default"``: the configuration's own (the hand-rolled
    tracker and the GTSAM window: what a plain ``gtvo run`` runs). ``mode`` goes to the config's ``mode`` field when gtvo has
    one; without it only ``"track"`` (frame-to-keyframe tracking) exists and any other mode raises
    :class:`ModeUnavailable`.
    """
    from gtvo.config import OdometryConfig, SolverConfig  # noqa: PLC0415

    names = {f.name for f in dataclasses.fields(OdometryConfig)}
    kwargs: dict[str, Any] = {**({} if solver == "default" else {"solver": SolverConfig.both(solver)}), **overrides}
    if "mode" in names:
        kwargs["mode"] = mode
    elif mode != "track":
        raise ModeUnavailable(f"gtvo has no mode {mode!r} (OdometryConfig has no 'mode' field)")
    try:
        return OdometryConfig(**kwargs)
    except InputError as exc:
        raise ModeUnavailable(str(exc)) from exc


def run_gtvo(camera: Any, frames: list[Frame], config: Any, record_predictions: bool = False) -> dict[str, Any]:
    """Feed preloaded ``frames`` to a ``VisualOdometry``; its trajectory, timing and counters.

    With ``record_predictions``, the motion model's guess of each frame's pose (the tracker's
    initial guess; ``VisualOdometry._predict``, a pure function of the state, called outside the
    timed part) is kept too: ``"predictions"`` maps frame position -> 4x4 ``T_world_cam``.
    """
    from gtvo.odometry import VisualOdometry  # noqa: PLC0415

    vo = VisualOdometry(camera, config)
    times = np.empty(len(frames))
    predictions: dict[int, np.ndarray] = {}
    for k, frame in enumerate(frames):
        if record_predictions and vo.estimates:
            predictions[k] = np.asarray(vo.motion.predict(frame.timestamp).matrix())
        t0 = time.perf_counter()
        vo.process(frame)
        if k == len(frames) - 1:
            vo.finish()  # the last keyframes' window optimisation: part of the run's time
        times[k] = time.perf_counter() - t0
    iters = [e.tracking.iterations for e in vo.estimates if e.tracking is not None]
    reasons: dict[str, int] = {}
    for e in vo.estimates:
        if e.reinitialised and e.tracking is not None:
            key = re.sub(r"\d+(\.\d+)?", "N", e.tracking.reason or "unknown")
            reasons[key] = reasons.get(key, 0) + 1
    return {
        "trajectory": vo.trajectory("gtvo"),
        "seconds": float(times.sum()),
        "keyframes": len(vo.keyframes),
        "failures": int(vo.failures),
        "tracking_iterations_mean": float(np.mean(iters)) if iters else None,
        "failure_reasons": reasons,
        "predictions": predictions,
        "vo": vo,
    }


def failure_details(vo: Any, seq: Sequence) -> list[dict[str, Any]]:
    """For each frame where gtvo's tracking failed: the reason, and how far from the ground-truth
    frame-to-frame motion (previous estimate -> this frame) the pose it kept (the motion-model
    prediction) and the pose the tracker had found are, translation (m) / rotation (deg)."""
    from gtvo.core.lie import invert_poses, rotation_angle  # noqa: PLC0415

    out = []
    est = vo.estimates
    for k, e in enumerate(est):
        if not (e.reinitialised and e.tracking is not None) or k == 0 or seq.gt_poses is None:
            continue
        i, p = e.index, est[k - 1]
        if not (np.isfinite(seq.gt_poses[i, 0, 0]) and np.isfinite(seq.gt_poses[p.index, 0, 0])):
            continue
        kf = max((kf for kf in vo.keyframes if kf.index < i), key=lambda kf: kf.index)
        T_tracked = kf.T_world_cam.compose(e.tracking.T_keyframe_frame).matrix()
        gt_rel = invert_poses(seq.gt_poses[p.index]) @ seq.gt_poses[i]
        row: dict[str, Any] = {"frame": i, "reason": e.tracking.reason}
        for name, T in (("kept", e.T_world_cam), ("tracked", T_tracked)):
            E = invert_poses(gt_rel) @ (invert_poses(p.T_world_cam) @ T)
            row[f"{name}_t_m"] = float(np.linalg.norm(E[:3, 3]))
            row[f"{name}_r_deg"] = float(np.degrees(rotation_angle(E[:3, :3])))
        out.append(row)
    return out


def score(est: Trajectory, seq: Sequence) -> dict[str, float | None]:
    """ATE, drift, RPE and max displacement of ``est`` (one pose per frame of ``seq``)."""
    out: dict[str, float | None] = {
        "max_disp_m": float(np.max(np.linalg.norm(est.positions - est.positions[0], axis=1)))}
    out.update(ate_m=None, ate_sim3_m=None, scale=None, drift_pct=None, rpe_t_m=None, rpe_r_deg=None, seg_t_pct=None,
               seg_r_deg_per_100m=None)
    if seq.gt_poses is None:
        return out
    has = np.isfinite(seq.gt_poses[:, 0, 0])[: len(est)]
    if has.sum() < 3:
        return out
    e = Trajectory(est.timestamps[has], est.poses[has], "est")
    g = Trajectory(seq.timestamps[: len(est)][has], seq.gt_poses[: len(est)][has], "gt")
    try:
        out["ate_m"] = ate(e, g, "se3").rmse
        out["ate_sim3_m"] = ate(e, g, "sim3").rmse
    except InputError:  # degenerate (e.g. a static clip): no unique alignment
        pass
    r = rpe(e, g, 1)
    out["rpe_t_m"], out["rpe_r_deg"] = r.translation.rmse, r.rotation_deg.rmse
    if g.path_length() >= MIN_DRIFT_PATH_M:
        out["drift_pct"] = drift_percent(e, g)
        seg = kitti_segment_errors(e, g, SEGMENT_LENGTHS_M, step=1)
        if seg is not None:
            out["seg_t_pct"], out["seg_r_deg_per_100m"] = seg.translation_percent, seg.rotation_deg_per_100m
    out["gt_path_m"] = float(g.path_length())
    if out["gt_path_m"] > 0:
        out["scale"] = float(e.path_length()) / out["gt_path_m"]
    return out


def reference_ms(frames: list[Frame], repeats: int = 5, timer: Any = time.perf_counter) -> float:
    """Median wall time (ms; ``timer=time.process_time``: this process's CPU time) of one OpenCV
    StereoSGBM (the peers' settings) on the first frame.

    Stereo: left against right; RGB-D: left against itself (same work per pixel). Measured in
    the same run as the rows, so ms/frame divided by it compares runs on a busy machine.
    """
    f = frames[0]
    left = to_uint8(f.left)
    right = to_uint8(f.right) if f.right is not None else left
    matcher = make_sgbm()
    ts = []
    for _ in range(repeats):
        t0 = timer()
        matcher.compute(left, right)
        ts.append(timer() - t0)
    return 1000.0 * float(np.median(ts))


def fmt(x: Any, spec: str) -> str:
    """``x`` formatted with ``spec``, or ``-`` for None."""
    return "-" if x is None else format(x, spec)


def markdown_table(header: list[str], rows: list[list[str]]) -> str:
    """A markdown table."""
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(r) + " |" for r in rows]
    return "\n".join(lines)


def load_frames(seq: Sequence, progress: bool = True) -> list[Frame]:
    """All frames of ``seq`` in memory (so runs time computation, not PNG decoding)."""
    idx: Any = range(len(seq))
    if progress:
        from tqdm import tqdm  # noqa: PLC0415

        idx = tqdm(idx, desc=f"loading {seq.name}", unit="frame", file=sys.stderr, leave=False)
    return [seq.frame(i) for i in idx]


__all__ = ["KITTI_SEQUENCE_1", "ModeUnavailable", "SHARED_DATA", "fmt", "gtvo_config", "load_frames",
           "failure_details", "markdown_table", "reference_ms", "run_gtvo", "score"]
