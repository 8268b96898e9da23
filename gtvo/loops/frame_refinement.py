"""Non-keyframe poses re-estimated against the final keyframes of a run (after loop closing).

During a run every frame that is not a keyframe is tracked once, against the latest keyframe, and
afterwards only moves with it (``T_world_f = T_world_k T_k_f``). That single alignment is the
frame's whole error relative to its keyframe: on the synthetic loops 9-10 mm RMS, and about the
same with the keyframe's depths refined by the window or set to the truth, and from the true pose
as the start (docs/loop_closure.md, "Non-keyframes"): it is the noise of one direct alignment of
~300 points, not a bias that re-tracking against the same keyframe could remove. No keyframe pose
graph touches it, so it bounds what loop closure can do.

:func:`refine_frames` therefore measures each such frame again against **every** final keyframe
within the tracker's range (``|t_q_f| * median(d_q) <= max_motion``, the bound of a loop edge,
:data:`gtvo.loops.direct_refinement.MAX_LOOP_MOTION`, and at most :data:`MAX_ROTATION_DEG` turned
away), by the frame tracker from the frame's current pose, and fuses the measurements
``T_world_q T_q_f`` into one pose (:func:`fuse_pose_measurements`: pose-only least squares, Huber at
the 99 % chi-square quantile).
Each measurement's covariance is the tracker's plus the uncertainty of the host ``q`` relative to
the frame's own keyframe ``k`` (:func:`chain_covariances`: the odometry edges' covariances composed
along the keyframe chain from ``k`` to ``q``), so a far host counts less than a near one, and the
keyframe poses, which stay as they are, are not assumed exact beyond what the odometry says.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Sequence

import gtsam
import numpy as np
from numpy.typing import NDArray

from gtvo.core.camera import PinholeCamera
from gtvo.core.image import to_float_gray
from gtvo.errors import InputError
from gtvo.frontend.keyframes import KeyframeConfig
from gtvo.frontend.stereo_depth import KeyframePoints
from gtvo.frontend.tracking import (PhotometricConfig, TrackingConfig, TrackingKeyframe, frame_pyramid,
                                   track_with_guesses)
from gtvo.loops.closure_graph import CHI2_6DOF_99
from gtvo.loops.direct_refinement import MAX_LOOP_MOTION, inverse_covariance_transport

F64 = NDArray[np.float64]

#: Huber threshold of the fusion on a measurement's whitened residual norm: the square root of the
#: 99 % quantile of chi-square with 6 degrees of freedom (a measurement that disagrees with the
#: others by more than its covariance allows counts linearly, not quadratically).
FUSION_HUBER_K = float(np.sqrt(CHI2_6DOF_99))

#: Largest rotation (degrees) between a host and the frame at the frame's current pose: the
#: keyframe rule's ``max_rotation_deg`` (beyond it the VO itself makes a new keyframe). Hosts that
#: look elsewhere (a camera turning on the spot stays within the motion bound of every keyframe)
#: cost an alignment each and, measured on TUM fr3/teddy, made the fused poses worse (6.3 hosts per
#: frame and 1.026x the open-loop ATE without this bound, 4.5 and 1.011x with it).
MAX_ROTATION_DEG = KeyframeConfig().max_rotation_deg


@dataclass
class FrameRefinement:
    """Result of :func:`refine_frames`.

    Attributes:
        poses: (N, 4, 4) ``T_world_cam`` of every frame: keyframes as given, refined frames fused,
            the others as given.
        hosts: (N,) per frame, the number of keyframes whose measurement was fused (0: unchanged).
    """

    poses: F64
    hosts: NDArray[np.int64]


def _pose3(T: F64) -> gtsam.Pose3:
    T = np.asarray(T, dtype=float)
    return gtsam.Pose3(gtsam.Rot3.ClosestTo(T[:3, :3]), T[:3, 3])


def chain_covariances(keyframe_poses: F64, edge_covariances: F64, k: int) -> F64:
    """Covariance of ``T_k_q`` (right perturbation, GTSAM order) for every keyframe ``q`` when the
    relative poses come from the chain of odometry edges between ``k`` and ``q``.

    Args:
        keyframe_poses: (K, 4, 4) ``T_world_kf``.
        edge_covariances: (K-1, 6, 6) covariance of ``T_r_(r+1)`` (edge ``r`` joins keyframes ``r``
            and ``r + 1``).
        k: the reference keyframe (its own covariance is zero).

    Composition ``T_k_c = T_k_b T_b_c`` carries ``cov(T_k_b)`` through ``Ad(T_b_c^-1)`` and adds
    ``cov(T_b_c)``; an edge walked backwards (``T_b_a = T_a_b^-1``) has the covariance
    :func:`inverse_covariance_transport` gives.

    Returns (K, 6, 6).
    """
    P = np.asarray(keyframe_poses, dtype=float)
    E = np.asarray(edge_covariances, dtype=float)
    n = len(P)
    if E.shape != (max(n - 1, 0), 6, 6):
        raise InputError(f"{E.shape[0] if E.ndim == 3 else E.shape} edge covariances for {n} keyframes "
                         f"(expected ({n - 1}, 6, 6))")
    if not 0 <= k < n:
        raise InputError(f"reference keyframe {k} is not one of the {n} keyframes")
    out = np.zeros((n, 6, 6))
    for step in (1, -1):
        cov = np.zeros((6, 6))
        r = k
        while 0 <= r + step < n:
            T_ab = np.linalg.inv(P[r]) @ P[r + step]  # a = r, b = r + step
            C_ab = E[r] if step == 1 else inverse_covariance_transport(np.linalg.inv(T_ab), E[r - 1])
            Ad = _pose3(np.linalg.inv(T_ab)).AdjointMap()
            cov = Ad @ cov @ Ad.T + C_ab
            r += step
            out[r] = cov
    return out


def fuse_pose_measurements(poses: Sequence[F64], covariances: Sequence[F64],
                           huber_k: float | None = FUSION_HUBER_K) -> F64:
    """The pose that best agrees with several measurements of it (4x4 each, covariances in its
    right-perturbation tangent): ``argmin_X sum_m rho(|| Log(T_m^-1 X) ||_{C_m})`` with Huber's
    ``rho`` at ``huber_k`` (None: plain least squares), solved by GTSAM's LM from the first
    measurement. One measurement is returned as it is.
    """
    if len(poses) == 0 or len(poses) != len(covariances):
        raise InputError(f"{len(poses)} pose measurements with {len(covariances)} covariances")
    if len(poses) == 1:
        return np.asarray(poses[0], dtype=float).copy()
    key = gtsam.symbol("f", 0)
    graph = gtsam.NonlinearFactorGraph()
    for T, C in zip(poses, covariances):
        C = np.asarray(C, dtype=float)
        noise = gtsam.noiseModel.Gaussian.Covariance(0.5 * (C + C.T))
        if huber_k is not None:
            noise = gtsam.noiseModel.Robust.Create(gtsam.noiseModel.mEstimator.Huber.Create(huber_k), noise)
        graph.add(gtsam.PriorFactorPose3(key, _pose3(T), noise))
    values = gtsam.Values()
    values.insert(key, _pose3(poses[0]))
    return gtsam.LevenbergMarquardtOptimizer(graph, values).optimize().atPose3(key).matrix()


def host_candidates(T_world_frame: F64, keyframe_poses: F64, median_inverse_depth: F64,
                    max_motion: float = MAX_LOOP_MOTION,
                    max_rotation_deg: float = MAX_ROTATION_DEG) -> NDArray[np.intp]:
    """Keyframes (positions in ``keyframe_poses``) within the tracker's range of a frame at
    ``T_world_frame``: ``|t_q_f| * median(d_q) <= max_motion`` and a rotation of at most
    ``max_rotation_deg`` between them."""
    T_q_f = np.linalg.inv(np.asarray(keyframe_poses, dtype=float)) @ np.asarray(T_world_frame, dtype=float)
    motion = np.linalg.norm(T_q_f[:, :3, 3], axis=1) * np.asarray(median_inverse_depth, dtype=float)
    cos = np.clip((np.trace(T_q_f[:, :3, :3], axis1=1, axis2=2) - 1.0) / 2.0, -1.0, 1.0)
    return np.flatnonzero((motion <= max_motion) & (np.degrees(np.arccos(cos)) <= max_rotation_deg))


def refine_frames(camera: PinholeCamera, frame_image: Callable[[int], NDArray], poses: F64, keyframes: Sequence[int],
                  keyframe_points: Sequence[KeyframePoints], edge_covariances: F64,
                  refine: Sequence[bool] | None = None, config: TrackingConfig | None = None,
                  max_motion: float = MAX_LOOP_MOTION, progress: bool = False,
                  photometric: PhotometricConfig | None = None) -> FrameRefinement:
    """Re-estimate every non-keyframe against the final keyframes (module docstring).

    Args:
        camera: the left camera (level 0).
        frame_image: the left image (grey levels or colour) of the pose at a position of ``poses``.
        poses: (N, 4, 4) ``T_world_cam`` of every frame, the keyframes at their final poses and
            the other frames moved with their keyframe (the starting guesses).
        keyframes: positions in ``poses`` of the keyframes, increasing.
        keyframe_points: per keyframe, its points (pixels, inverse depths, variances).
        edge_covariances: (K-1, 6, 6) covariance of the relative pose of consecutive keyframes.
        refine: per frame, whether its pose may be re-estimated (default: every non-keyframe); a
            frame whose pose is a prediction (lost, suspect) should be left out.
        config: the tracker's settings (default :class:`TrackingConfig`).
        max_motion: the largest ``|t_q_f| * median(d_q)`` of a host ``q``.
        progress: show a progress bar.
        photometric: the tracker's photometric model (the run's; default :class:`PhotometricConfig`).

    A frame keeps its pose when no host measures it (every alignment failed or left the range).
    """
    P = np.asarray(poses, dtype=float)
    kfs = [int(k) for k in keyframes]
    if len(kfs) == 0 or len(keyframe_points) != len(kfs) or kfs != sorted(set(kfs)) or kfs[-1] >= len(P):
        raise InputError(f"{len(kfs)} keyframe positions (increasing, below {len(P)}) for "
                         f"{len(keyframe_points)} keyframe point sets")
    mask = np.ones(len(P), bool) if refine is None else np.asarray(refine, bool).copy()
    if mask.shape != (len(P),):
        raise InputError(f"refine has {mask.shape[0]} entries for {len(P)} poses")
    mask[kfs] = False
    cfg = config or TrackingConfig()
    model = photometric or PhotometricConfig()
    K = P[kfs]
    med_d = np.array([float(np.median(p.inverse_depth)) if len(p) else np.inf for p in keyframe_points])
    owner = np.maximum(np.searchsorted(np.asarray(kfs), np.arange(len(P)), side="right") - 1, 0)
    trackers: dict[int, TrackingKeyframe] = {}
    chains: dict[int, F64] = {}
    out, hosts = P.copy(), np.zeros(len(P), np.int64)
    todo: Sequence[int] = np.flatnonzero(mask).tolist()
    if progress:
        from tqdm import tqdm  # noqa: PLC0415

        todo = tqdm(todo, desc="frame refinement", unit="frame", dynamic_ncols=True)
    for p in todo:
        k = int(owner[p])
        cand = [int(q) for q in host_candidates(P[p], K, med_d, max_motion) if len(keyframe_points[q])]
        if not cand:
            continue
        pyr = frame_pyramid(to_float_gray(frame_image(p), f"frame {p} image"), cfg.levels, model.clip_range)
        if k not in chains:
            chains[k] = chain_covariances(K, edge_covariances, k)
        meas, covs = [], []
        for q in cand:
            if q not in trackers:
                pts = keyframe_points[q]
                trackers[q] = TrackingKeyframe(camera, to_float_gray(frame_image(kfs[q]), f"keyframe {kfs[q]} image"),
                                               pts.pixels, pts.inverse_depth, pts.variance, (0.0, 0.0), cfg,
                                               photometric=model)
            r = track_with_guesses(trackers[q], pyr, [_pose3(np.linalg.inv(K[q]) @ P[p])])
            T_q_f = r.T_keyframe_frame.matrix()
            if (not r.success or not np.all(np.isfinite(r.covariance))
                    or np.linalg.norm(T_q_f[:3, 3]) * med_d[q] > max_motion):
                continue
            Ad = _pose3(np.linalg.inv(T_q_f)).AdjointMap()  # the host's uncertainty, carried to the frame
            meas.append(K[q] @ T_q_f)
            covs.append(r.covariance + Ad @ chains[k][q] @ Ad.T)
        if meas:
            out[p] = fuse_pose_measurements(meas, covs)
            hosts[p] = len(meas)
    return FrameRefinement(out, hosts)
