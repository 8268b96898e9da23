"""Marginalisation of a keyframe that leaves the window into a prior on the others (docs/window.md)."""

from __future__ import annotations

import gtsam
import numpy as np
from numpy.typing import NDArray

from gtvo.core.keys import calibration_key, is_pose_key, rig_offset_key
from gtvo.window.config import MarginalPrior, values_subset
from gtvo.window.problem import TargetChoice, WindowProblem, host_factor, key_ordering, visible_targets

FloatArray = NDArray[np.float64]


def marginalize(problem: WindowProblem, position: int = 0) -> MarginalPrior:
    """Marginalise ``problem.keyframes[position]`` and its points; return the prior on the others.

    The factors touching it (its host factor into the keyframes that see its points, and every
    factor of the problem's graph on its variables: its affine prior, the motion priors it is part
    of, the wheel factors) and the factors on no keyframe's variable (the rig offset's and the
    wheel calibration's priors, added once, as the gauge prior), with the gauge prior or the
    previous marginalisation prior, are linearised at the current state; its variables
    (:meth:`WindowProblem.keyframe_keys`) are eliminated; what is left (a quadratic on the
    remaining keyframes and the problem's other variables) is the new prior, with the current
    state as its fixed linearisation point. Residuals of other hosts' points in the leaving
    keyframe are not part of it (they are dropped). The rig offset and the wheel calibration are
    never eliminated: the prior carries what the leaving keyframe said about them.
    """
    keyframes = problem.keyframes
    kf = keyframes[position]
    members = problem.members
    targets = (members.targets[position] if members.targets is not None else
               visible_targets(problem.camera, keyframes, problem.config, TargetChoice(hosts=[position]))[0])
    leaving = problem.keyframe_keys(kf)
    touching = set(leaving)
    on_keyframes = {key for other in keyframes for key in problem.keyframe_keys(other)}
    graph = gtsam.NonlinearFactorGraph()
    if targets:
        graph.add(host_factor(problem, position, targets))
    factors = problem.factors
    for i in range(problem.host_position):  # its affine prior and motion priors, then the gauge prior
        if i not in problem.gauge_factors and touching.intersection(factors.at(i).keys()):
            graph.add(factors.at(i))
    if problem.marginal is None:
        for i in problem.gauge_factors:
            graph.add(factors.at(i))
    else:
        for f in problem.marginal.nonlinear_factors():
            graph.add(f)
    for i in range(problem.host_position, factors.size()):
        keys = factors.at(i).keys()
        if touching.intersection(keys) or not on_keyframes.intersection(keys):
            graph.add(factors.at(i))
    values = problem.values()
    linear = graph.linearize(values)
    _, remaining = linear.eliminatePartialMultifrontal(key_ordering(leaving))
    present = set(remaining.keyVector())
    keys = [key for other in keyframes for key in problem.keyframe_keys(other) if key in present]
    firsts = [k for k in (rig_offset_key(), calibration_key()) if k in present]
    keys += firsts + [k for k in problem.variables.keys() if k in present and k not in firsts and k not in keys]
    dims = [6 if is_pose_key(key) else int(np.asarray(values.atVector(key)).size) for key in keys]
    aug = remaining.augmentedHessian(key_ordering(keys))
    n = aug.shape[0] - 1
    H = 0.5 * (aug[:n, :n] + aug[:n, :n].T)
    return MarginalPrior(keys, dims, H, aug[:n, n].copy(), float(aug[n, n]), values_subset(values, keys), remaining)
