"""Direct (photometric) refinement of a verified loop: the metric relative pose of a loop edge.

PnP on ORB keypoints is a good *verifier* (a revisit or not) but a poor *measurement*: at the
resolution of the VO and with the texture far away, a few hundred ORB points on one depth
layer leave the pitch / vertical-translation (and yaw / sideways) pairs nearly unobservable, and
the estimate wanders along them by degrees and decimetres (docs/loop_closure.md, "Why loop
closure made the trajectory worse"). The VO's own odometry edges are direct alignments of a
frame against a keyframe's semi-dense points, millimetre-accurate. A loop edge that enters the
same pose graph must be of the same kind, or its information is on another scale.

:func:`refine_loop` therefore re-measures ``T_i_j`` the way the VO measures an odometry edge:
the query keyframe ``i`` hosts its points (pixels and inverse depths), the candidate keyframe
``j``'s left image is the target, and :func:`gtvo.frontend.tracking.track_with_guesses` (coarse to fine,
affine brightness estimated) starts from the PnP pose. The result is ``T_keyframe_frame =
T_i_j``, with the tracker's covariance (the inverse Gauss-Newton Hessian at level 0), the same
model as the odometry edges' covariance. Hosting the points on the query keyframe (not on ``j``)
keeps several loops to one old keyframe from sharing one set of depth errors.
"""

from __future__ import annotations

from dataclasses import dataclass

import gtsam
import numpy as np
from numpy.typing import NDArray

from gtvo.core.camera import PinholeCamera
from gtvo.core.image import to_float_gray
from gtvo.frontend.stereo_depth import KeyframePoints
from gtvo.frontend.tracking import (PhotometricConfig, TrackingConfig, TrackingKeyframe, TrackingResult,
                                   track_with_guesses)

F64 = NDArray[np.float64]

#: Largest loop baseline relative to the host keyframe's median depth, ``|t_i_j| * median(d_i)``,
#: measured by direct alignment: the same quantity as the VO's keyframe rule
#: (``OdometryConfig.keyframes.max_motion`` = 0.3, up to which frames are tracked against a keyframe)
#: with some room. Beyond it the views differ by parallax and occlusions the photometric model
#: does not describe, and the alignments are off by 0.5-2 % of the baseline, consistently both ways
#: (docs/loop_closure.md, "Why loop closure made the trajectory worse").
MAX_LOOP_MOTION = 0.4


@dataclass(frozen=True)
class RefinedLoop:
    """A loop edge measured by direct alignment.

    Attributes:
        T_i_j: 4x4 pose of keyframe ``j`` in keyframe ``i``'s camera frame.
        information: 6x6 information of ``T_i_j`` (GTSAM order [rot, trans], right perturbation):
            the inverse of the tracker's covariance.
        tracking: the tracker's full result (rms, valid points, affine brightness).
    """

    T_i_j: F64
    information: F64
    tracking: TrackingResult


def refine_loop(camera: PinholeCamera, host_image: NDArray, host_points: KeyframePoints, target_image: NDArray,
                T_i_j_guess: F64, config: TrackingConfig | None = None,
                photometric: PhotometricConfig | None = None) -> RefinedLoop | None:
    """Direct alignment of keyframe ``j``'s image to keyframe ``i``'s points, from ``T_i_j_guess``.

    Args:
        camera: the left camera (level 0).
        host_image: keyframe ``i``'s left image (grey levels).
        host_points: keyframe ``i``'s points with inverse depths (the VO's, or freshly initialised).
        target_image: keyframe ``j``'s left image.
        T_i_j_guess: initial 4x4 ``T_i_j`` (e.g. the PnP verification's).
        config: tracker settings (default :class:`TrackingConfig`).
        photometric: the tracker's photometric model (the run's; default :class:`PhotometricConfig`).

    Returns None when the tracker fails (too few valid points, residuals that say the pose is
    wrong) or its covariance is singular: such a loop has no metric measurement.
    """
    if len(host_points) == 0:
        return None
    cfg = config or TrackingConfig()
    host = TrackingKeyframe(camera, to_float_gray(host_image, "loop keyframe image"), host_points.pixels,
                            host_points.inverse_depth, host_points.variance, (0.0, 0.0), cfg,
                            photometric=photometric)
    target = to_float_gray(target_image, "loop candidate image")
    T0 = np.asarray(T_i_j_guess, dtype=float)
    guess = gtsam.Pose3(gtsam.Rot3.ClosestTo(T0[:3, :3]), T0[:3, 3])
    result = track_with_guesses(host, target, [guess])
    cov = result.covariance
    if not result.success or not np.all(np.isfinite(cov)):
        return None
    info = np.linalg.inv(0.5 * (cov + cov.T))
    return RefinedLoop(result.T_keyframe_frame.matrix(), 0.5 * (info + info.T), result)


def inverse_covariance_transport(T_j_i: F64, covariance_j_i: F64) -> F64:
    """Covariance of ``T_i_j = T_j_i^-1`` (right perturbation) from that of ``T_j_i``.

    ``(T Exp(xi))^-1 = Exp(-xi) T^-1 = T^-1 Exp(-Ad_T xi)``, so the covariance is
    ``Ad_T C Ad_T^T`` with ``Ad_T`` the adjoint of ``T = T_j_i`` (GTSAM order [rot, trans]).
    """
    T = np.asarray(T_j_i, dtype=float)
    Ad = gtsam.Pose3(gtsam.Rot3.ClosestTo(T[:3, :3]), T[:3, 3]).AdjointMap()
    return Ad @ np.asarray(covariance_j_i, dtype=float) @ Ad.T


def consistency_chi2(forward: RefinedLoop, backward: RefinedLoop) -> float:
    """Chi-square of the disagreement of ``forward`` (``T_i_j``, points of ``i``) and ``backward``
    (``T_j_i``, points of ``j``): ``d = Log(T_i_j^-1 T_j_i^-1)`` against the sum of both
    covariances, both expressed for ``T_i_j``. About chi-square with 6 degrees of freedom when the
    two alignments found the same pose within their noise.
    """
    d = np.asarray(gtsam.Pose3.Logmap(gtsam.Pose3(np.linalg.inv(forward.T_i_j) @ np.linalg.inv(backward.T_i_j))))
    C = np.linalg.inv(forward.information) + inverse_covariance_transport(backward.T_i_j,
                                                                          np.linalg.inv(backward.information))
    return float(d @ np.linalg.solve(C, d))


def loop_motion(T_i_j: F64, points_i: KeyframePoints) -> float:
    """``|t_i_j| * median(d_i)``: the loop's baseline relative to the host's median depth."""
    return float(np.linalg.norm(np.asarray(T_i_j, dtype=float)[:3, 3]) * np.median(points_i.inverse_depth))


def refine_loop_both_ways(camera: PinholeCamera, image_i: NDArray, points_i: KeyframePoints, image_j: NDArray,
                          points_j: KeyframePoints, T_i_j_guess: F64, config: TrackingConfig | None = None,
                          max_chi2: float = 16.812, max_motion: float = MAX_LOOP_MOTION,
                          photometric: PhotometricConfig | None = None) -> RefinedLoop | None:
    """:func:`refine_loop` with ``i`` as the host, checked by the same alignment with ``j`` as the host.

    The two alignments use different points, depths and images as reference; a loop whose
    geometry the photometric model does not explain (a wrong local minimum, a view change too
    large for the depths, occlusions) gives two poses that disagree by more than their
    covariances allow. Returns the forward result when :func:`consistency_chi2` is below
    ``max_chi2`` (default: the 99 % quantile of chi-square with 6 degrees of freedom) and
    :func:`loop_motion` is at most ``max_motion``, else None.
    """
    forward = refine_loop(camera, image_i, points_i, image_j, T_i_j_guess, config, photometric)
    if forward is None or loop_motion(forward.T_i_j, points_i) > max_motion:
        return None
    backward = refine_loop(camera, image_j, points_j, image_i, np.linalg.inv(forward.T_i_j), config, photometric)
    if backward is None or consistency_chi2(forward, backward) > max_chi2:
        return None
    return forward
