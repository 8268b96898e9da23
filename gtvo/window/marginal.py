"""Marginalisation of a keyframe that leaves the window into a prior on the others (docs/window.md)."""

from __future__ import annotations

from typing import TYPE_CHECKING, Sequence

import gtsam
import numpy as np
from numpy.typing import NDArray

from gtvo.core.keys import affine_key, calibration_key, pose_key, rig_offset_key
from gtvo.core.camera import PinholeCamera
from factors.params import DEFAULT_PHOTOMETRIC, PhotometricConfig
from gtvo.window.config import MarginalPrior, WindowConfig, WindowKeyframe
from gtvo.window.config import values_subset
from gtvo.window.problem import (gauge_noise, host_factor, key_ordering, motion_factors, needs_rig_prior, rig_prior,
                                 visible_targets, wheel_carried, wheel_factors, window_values)

if TYPE_CHECKING:
    from gtvo.window.wheel import WheelCalibration

FloatArray = NDArray[np.float64]


def marginalize(camera: PinholeCamera, baseline: float | None, keyframes: Sequence[WindowKeyframe],
                config: WindowConfig, marginal: MarginalPrior | None, position: int = 0,
                rig_offset: FloatArray | None = None, *,
                photometric: PhotometricConfig = DEFAULT_PHOTOMETRIC,
                wheel: "WheelCalibration | None" = None) -> MarginalPrior:
    """Marginalise ``keyframes[position]`` and its points (residuals of the ``photometric`` model);
    return the prior on the others.

    The factors touching it (its host factor into the keyframes that see its points, its affine
    prior, the motion priors it is part of, the gauge prior or the previous marginal prior) are
    linearised at the current state;
    its pose and affine are eliminated; what is left (a quadratic on the remaining keyframes) is
    the new prior, with the current state as its fixed linearisation point. Residuals of other
    hosts' points in the leaving keyframe are not part of it (they are dropped).
    With ``rig_offset`` (its current estimate) the rig offset is a variable of the leaving host's
    factor; it is never eliminated, so the prior carries what the leaving keyframe said about it
    (and its zero-mean prior, added here the first time, as the gauge prior). With ``wheel`` the
    wheel factors touching the leaving keyframe join too, and the calibration is carried the same
    way (its prior added here the first time).
    """
    kf = keyframes[position]
    targets = visible_targets(camera, keyframes, config, hosts=[position])[0]
    graph = gtsam.NonlinearFactorGraph()
    if targets:
        graph.add(host_factor(camera, baseline, keyframes, position, targets, config, rig=rig_offset is not None,
                              photometric=photometric))
    aff_noise = gtsam.noiseModel.Diagonal.Sigmas(np.asarray(config.affine_sigma, dtype=float))
    graph.add(gtsam.PriorFactorVector(affine_key(kf.index), np.asarray(kf.affine_prior, dtype=float), aff_noise))
    for k, f in motion_factors(keyframes, config):
        if k <= position <= k + 2:
            graph.add(f)
    if marginal is None:
        graph.add(gtsam.PriorFactorPose3(pose_key(kf.index), kf.pose, gauge_noise(config, 6)))
        graph.add(gtsam.PriorFactorVector(affine_key(kf.index), kf.affine.copy(), gauge_noise(config, 2)))
    else:
        for f in marginal.nonlinear_factors():
            graph.add(f)
    if needs_rig_prior(rig_offset, marginal):
        graph.add(rig_prior(config))
    if wheel is not None:
        for k, f in wheel_factors(keyframes, wheel):
            if k <= position <= k + 1:
                graph.add(f)
        if not wheel_carried(marginal):
            graph.add(wheel.prior_factor())
    values = window_values(keyframes, rig_offset, wheel)
    linear = graph.linearize(values)
    leaving = [pose_key(kf.index), affine_key(kf.index)]
    _, remaining = linear.eliminatePartialMultifrontal(key_ordering(leaving))
    present = set(remaining.keyVector())
    keys, dims = [], []
    for other in keyframes:
        for key, dim in ((pose_key(other.index), 6), (affine_key(other.index), 2)):
            if key in present:
                keys.append(key)
                dims.append(dim)
    if rig_offset_key() in present:
        keys.append(rig_offset_key())
        dims.append(2)
    if wheel is not None and calibration_key() in present:
        keys.append(calibration_key())
        dims.append(wheel.size)
    aug = remaining.augmentedHessian(key_ordering(keys))
    n = aug.shape[0] - 1
    H = 0.5 * (aug[:n, :n] + aug[:n, :n].T)
    return MarginalPrior(keys, dims, H, aug[:n, n].copy(), float(aug[n, n]), values_subset(values, keys), remaining)
