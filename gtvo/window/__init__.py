"""Sliding-window joint optimisation of keyframe poses, affine brightness and inverse depths.

A window holds the last ``N`` keyframes (default 7). Each keyframe hosts its points (pixels,
inverse depths ``d`` and variances ``V`` from stereo or an RGB-D sensor); the cost is

    E = sum_h [ sum_{t in targets(h)} sum_n rho(|sqrt(W) r_{n,h->t}|)      (photometric, factors.photometric)
                + sum_n rho(|sqrt(lambda W) r^stereo_n|)                   (stereo energy, right image)
                + sum_n (d_n - d_n^0)^2 / (2 V_n) ]                         (depth prior: RGB-D only)
        + sum_k |(a_k, b_k) - (a_k^0, b_k^0)|^2_Sigma_affine / 2            (weak affine priors)
        + sum_k |v_{k+1,k+2} - v_{k,k+1}|^2_Sigma_acc / 2                  (motion smoothness)
        + gauge prior on the oldest keyframe (pose and affine)  OR  the marginalisation prior

(the motion term: a :class:`factors.smoothness.ConstantVelocityFactor` on every three
consecutive keyframes with timestamps, ``v`` their body-frame velocity twists, sigmas the
``acceleration_sigma`` times the time between the two velocities) over the keyframes' poses
``x_k`` (``T_world_cam``, GTSAM Pose3, right perturbation), affine
brightness ``(a_k, b_k)`` and all inverse depths. ``targets(h)``: the other keyframes of the
window into which at least ``min_visible_points`` / ``min_visible_fraction`` of the host's points
project (checked by projection at the window's starting state). Two solvers minimise the same E:

* :func:`solve_gtsam`: one :class:`factors.smart.HostPointsFactor` per host (depths
  Schur-eliminated inside the factor), priors as GTSAM factors, the marginalisation prior as
  ``gtsam.LinearContainerFactor``; solved by ``gtsam.LevenbergMarquardtOptimizer``.
* :func:`solve_handrolled`: Levenberg-Marquardt on the reduced camera system (poses + affines)
  assembled in numpy from the kernels of :mod:`factors.photometric`, inverse depths eliminated by
  the Schur complement and recovered by back-substitution.

:class:`SlidingWindowOptimizer` keeps the window: :meth:`~SlidingWindowOptimizer.add_keyframe`
marginalises the oldest keyframe (and the points it hosts) when the window is full: the factors
touching it are linearised at the current estimate, it is eliminated
(``GaussianFactorGraph.eliminatePartialMultifrontal``) and the marginal on the remaining keyframes
is kept as a prior with a fixed linearisation point. Residuals of other hosts' points in the
leaving keyframe are dropped (as DSO does). Details and the consistency choice: docs/window.md.

With a ``rig_offset`` (stereo, LM backend) the stereo rig's rectification error ``(delta_x,
delta_y)`` of the right image is one more variable of the window, shared by every host's stereo
term and carried by the marginalisation prior (docs/window.md, "Rig calibration").

``WindowConfig(backend="fixed_lag")`` hands the window to ``gtsam.IncrementalFixedLagSmoother``
instead (keyframe sequence number as timestamp, lag ``size - 0.5``): the smoother marginalises
leaving keyframes with their host factor (depths frozen in the marginal); docs/window.md.
"""

from gtvo.core.keys import affine_key, pose_key
from gtvo.window.config import MarginalPrior, WindowConfig, WindowKeyframe, WindowResult, WindowSolverName
from gtvo.window.gtsam_solver import solve_gtsam
from gtvo.window.handrolled import solve_handrolled, window_cost
from gtvo.window.marginal import marginalize
from gtvo.window.optimizer import SlidingWindowOptimizer
from gtvo.window.rig import RigOffset, rig_warning
from gtvo.window.problem import (RigVariable, TargetChoice, WindowMembers, WindowProblem, WindowSettings, build_graph,
                                 host_factor, motion_factors, prior_factors, visible_targets)

__all__ = ["MarginalPrior", "RigOffset", "RigVariable", "SlidingWindowOptimizer", "TargetChoice", "WindowConfig",
           "WindowKeyframe", "WindowMembers", "WindowProblem", "WindowResult", "WindowSettings", "WindowSolverName",
           "affine_key", "build_graph", "host_factor", "marginalize", "motion_factors", "pose_key", "prior_factors",
           "rig_warning", "solve_gtsam", "solve_handrolled", "visible_targets", "window_cost"]
