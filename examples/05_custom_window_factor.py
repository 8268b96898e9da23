"""
A window factor gtvo does not have, added to the window of a real run: a GPS-like prior on every
keyframe's position, in the style of GTSAM's CustomFactorExample (an error function with its
Jacobian, a gtsam.CustomFactor, a graph). The window's problem (gtvo.window.WindowProblem) keeps
every factor that is not a photometric host factor in one gtsam.NonlinearFactorGraph that both
window solvers consume, so the new factor is one line: problem.factors.add(factor). The recipe:
docs/extending.md, "A new window factor".

The run is 25 frames of KITTI_sequence_1 of the shared data when it is there ($GTVO_SHARED_DATA,
or ../shared/data beside the checkout), else of gtvo's synthetic stereo sequence; the "GPS" is
the ground truth's keyframe positions with 5 cm of seeded noise.
Run from the checkout's root: python examples/05_custom_window_factor.py
"""

import copy
import os
from functools import partial
from pathlib import Path

import gtsam
import numpy as np
from gtsam.utils.numerical_derivative import numericalDerivative11

import gtvo
from gtvo.core.keys import pose_key
from gtvo.datasets.synthetic import make_synthetic_sequence
from gtvo.window import WindowConfig, WindowMembers, WindowProblem, WindowSettings, solve_gtsam, solve_handrolled

GPS_SIGMA = 0.05  # m, on each axis


def error_position(measurement, this, values, jacobians):
    """GPS-like position prior: the keyframe's position minus the measured one (3, m).

    ``this.keys()[0]`` is the keyframe's pose key (T_world_cam); with GTSAM's right perturbation
    ``T exp(xi)``, ``xi = (omega, v)``, the position moves by ``R v``: the Jacobian is ``[0 | R]``.
    """
    T = values.atPose3(this.keys()[0])
    if jacobians is not None:
        jacobians[0] = np.hstack([np.zeros((3, 3)), T.rotation().matrix()])
    return np.asarray(T.translation(), dtype=float) - measurement


def gps_factor(pose_key, measured_position):
    """The prior as a GTSAM factor on ``pose_key`` (sigma :data:`GPS_SIGMA` per axis)."""
    noise = gtsam.noiseModel.Isotropic.Sigma(3, GPS_SIGMA)
    return gtsam.CustomFactor(noise, [pose_key], partial(error_position, np.asarray(measured_position, dtype=float)))


def the_sequence():
    """KITTI_sequence_1 of the shared data if present, else gtvo's synthetic stereo sequence."""
    shared = Path(os.environ.get("GTVO_SHARED_DATA", Path(__file__).resolve().parents[2] / "shared" / "data"))
    kitti = shared / "kitti_stereo_sample" / "KITTI_sequence_1"
    if kitti.is_dir():
        return gtvo.open_sequence(kitti, max_frames=25)
    return make_synthetic_sequence(n_frames=25)


def main():
    """Main runner."""
    # 1. The factor's Jacobian against a numerical derivative, at a pose away from the identity
    T = gtsam.Pose3(gtsam.Rot3.RzRyRx(0.1, -0.2, 0.3), np.array([1.0, 2.0, 3.0]))
    measured = np.array([1.1, 1.9, 3.2])
    factor = gps_factor(pose_key(0), measured)
    values = gtsam.Values()
    values.insert(pose_key(0), T)
    analytic = np.zeros((3, 6))
    jacobians = [analytic]
    error_position(measured, factor, values, jacobians)
    numeric = numericalDerivative11(lambda pose: error_position(measured, factor, _one(pose), None), T)
    print(f"Jacobian: largest difference to the numerical one {np.abs(jacobians[0] - numeric).max():.2e}")

    # 2. A real run: the odometry over the first frames; its window's keyframes at the end
    seq = the_sequence()
    vo = gtvo.VisualOdometry(seq.camera, gtvo.OdometryConfig(mode="window", solver="gtsam"))
    for frame in seq:
        vo.process(frame)
    vo.finish()
    keyframes = vo.window.every_keyframe()  # the last window (the others left with their images)
    gt = np.linalg.inv(seq.gt_poses[0]) @ np.asarray(seq.gt_poses)  # from the first camera, as the run's world
    truth = {kf.index: gt[kf.index][:3, 3] for kf in keyframes}
    print(f"{seq.name}: {len(seq)} frames, the last window has {len(keyframes)} keyframes "
          f"({', '.join(str(kf.index) for kf in keyframes)})")

    # 3. "GPS" positions: the ground truth with seeded noise, one per keyframe
    rng = np.random.default_rng(7)
    gps = {index: p + rng.normal(0.0, GPS_SIGMA, 3) for index, p in truth.items()}

    # 4. The window's problem over these keyframes (what the window solves), and the one line:
    #    the GPS factors go into its graph of non-host factors. The GPS now fixes where the window
    #    is in the world, so the gauge prior on the oldest keyframe is loosened (1 m, 1 rad).
    def problem_with_gps(members):
        problem = WindowProblem.build(WindowMembers(seq.camera.left, seq.camera.baseline, members),
                                      WindowSettings(WindowConfig(max_iterations=10, gauge_sigma=1.0)))
        for kf in members:
            problem.factors.add(gps_factor(pose_key(kf.index), gps[kf.index]))
        return problem

    # 5. Solve it with GTSAM's LM and with the hand-rolled LM: both consume the same graph
    error = {"window (no GPS)": _position_error(keyframes, truth)}
    for name, solve in (("GTSAM LM", solve_gtsam), ("hand-rolled LM", solve_handrolled)):
        members = copy.deepcopy(keyframes)
        result = solve(problem_with_gps(members))
        error[f"{name} with GPS"] = _position_error(members, truth)
        print(f"{name}: cost {result.initial_cost:.6g} -> {result.cost:.6g} in {result.iterations} iterations")

    # 6. Where the keyframes are against the ground truth (RMS over the window's keyframes)
    for name, e in error.items():
        print(f"position error, {name}: {e * 100:.2f} cm")


def _one(pose):
    values = gtsam.Values()
    values.insert(pose_key(0), pose)
    return values


def _position_error(keyframes, truth):
    return float(np.sqrt(np.mean([np.sum((np.asarray(kf.pose.translation()) - truth[kf.index]) ** 2)
                                  for kf in keyframes])))


if __name__ == "__main__":
    main()
