"""
A 2-D pose graph whose odometry edges calibrate the wheel odometry while the graph is optimised:
a robot drives a winding loop twice with biased wheel odometry; loop edges tie the second lap to the
first, a stretch of scan-matched motions gives the metric scale, and the 3x3 calibration X
(raw motion u -> true motion X u, docs/odometry_calibration.md) is a variable of the graph.

The same loop graph without the calibration is then optimised by gtvo.posegraph, and the whole
joint calibration is done again in one call by gtvo.wheel_calibration.joint_calibration.
Run from the checkout's root: python examples/03_pose_graph_with_odometry_calibration.py
"""

import gtsam
import numpy as np
from gtsam.symbol_shorthand import C, X  # our own keys: X(i) poses (Pose2), C(0) the calibration

import gtvo.posegraph as pg
from factors.odometry_calibration import calibrated_odometry_factor, linear_calibration_factor
from gtvo.wheel_calibration import LoopClosure, PosePrior, integrate_motions, joint_calibration, position_rmse

# What the wheels get wrong: the true motion is X_TRUE times the raw one (scale, slip, heading)
X_TRUE = np.array([[1.04, 0.0, 0.0], [0.01, 1.0, 0.0], [0.0, 0.0, 0.97]])
ODOMETRY_SIGMAS = np.array([0.01, 0.01, 0.005])   # x, y (m), theta (rad) per step
LOOP_SIGMAS = np.array([0.05, 0.05, 0.01])
ODOMETRY_NOISE = gtsam.noiseModel.Diagonal.Sigmas(ODOMETRY_SIGMAS)
LOOP_NOISE = gtsam.noiseModel.Diagonal.Sigmas(LOOP_SIGMAS)


def winding_loop(laps=2, steps=64):
    """True motions (x, y, theta) of a winding loop of ``steps`` steps of about 0.5 m, driven ``laps`` times."""
    k = np.arange(steps)
    lap = np.c_[0.5 + 0.2 * np.sin(2 * np.pi * k / 8), 0.05 * np.cos(2 * np.pi * k / 4),
                2 * np.pi / steps + 0.3 * np.sin(2 * np.pi * k / 16)]
    return np.tile(lap, (laps, 1))


def pose_graph_2d(poses, edges):
    """A :class:`gtvo.posegraph.PoseGraph` of (N, 3) poses (x, y, theta) and edges (i, j, Pose2, sigmas)."""
    as_pose2 = [gtsam.Pose2(*p) for p in poses]
    return pg.PoseGraph(dim=2, ids=np.arange(len(poses)), rotations=np.array([p.rotation().matrix() for p in as_pose2]),
                        translations=np.asarray(poses)[:, :2], has_vertices=True,
                        edge_i=np.array([e[0] for e in edges]), edge_j=np.array([e[1] for e in edges]),
                        meas_rotations=np.array([e[2].rotation().matrix() for e in edges]),
                        meas_translations=np.array([e[2].translation() for e in edges]),
                        information=np.array([np.diag(1 / np.asarray(e[3]) ** 2) for e in edges]))


def main():
    """Main runner."""
    # 1. Simulate: the true path, the raw wheel odometry (biased and noisy), loop edges between laps
    rng = np.random.default_rng(0)
    true_motions = winding_loop()
    truth = integrate_motions(true_motions)
    raw = true_motions @ np.linalg.inv(X_TRUE).T + rng.normal(0, ODOMETRY_SIGMAS, true_motions.shape)
    lap = len(true_motions) // 2
    loops = [(i, i + lap) for i in range(0, lap, 8)]  # the same place on both laps
    loop_edges = {(i, j): gtsam.Pose2(*truth[i]).between(gtsam.Pose2(*truth[j])) for i, j in loops}

    # 2. Create a factor graph container: a prior on the first pose (the gauge)
    graph = gtsam.NonlinearFactorGraph()
    graph.add(gtsam.PriorFactorPose2(X(0), gtsam.Pose2(), gtsam.noiseModel.Isotropic.Sigma(3, 1e-4)))

    # 3. Odometry edges through the calibration: the measurement of x_i -> x_i+1 is Pose2(X u_i)
    for i, u in enumerate(raw):
        graph.add(calibrated_odometry_factor(X(i), X(i + 1), C(0), u, ODOMETRY_NOISE))

    # 4. Loop edges: the second lap seen from the first (e.g. verified place recognition)
    for (i, j), motion in loop_edges.items():
        graph.add(gtsam.BetweenFactorPose2(X(i), X(j), motion, LOOP_NOISE))

    # 5. Calibration factors: the first 16 motions were also measured by a scan matcher (the metric
    #    scale), each a unary factor e = u_ref - X u on the calibration
    scan_matched = true_motions[:16] + rng.normal(0, 0.002, (16, 3))
    for u, reference in zip(raw[:16], scan_matched):
        graph.add(linear_calibration_factor(C(0), u, reference, ODOMETRY_NOISE))

    # 6. Initial estimate: dead reckoning of the raw motions, X at the identity
    dead_reckoning = integrate_motions(raw)
    initial = gtsam.Values()
    for i, (x, y, theta) in enumerate(dead_reckoning):
        initial.insert(X(i), gtsam.Pose2(x, y, theta))
    initial.insert(C(0), np.eye(3).ravel())

    # 7. Optimise with Levenberg-Marquardt
    result = gtsam.LevenbergMarquardtOptimizer(graph, initial, gtsam.LevenbergMarquardtParams()).optimize()
    X_found = result.atVector(C(0)).reshape(3, 3)
    poses = np.array([[p.x(), p.y(), p.theta()] for p in (result.atPose2(X(i)) for i in range(len(truth)))])
    print(f"{len(truth)} poses, {len(loops)} loop edges; calibration X found (true in brackets):")
    for row, true_row in zip(X_found, X_TRUE):
        print("  " + "  ".join(f"{v:6.3f} ({t:5.2f})" for v, t in zip(row, true_row)))

    # 8. The same loops without the calibration: a plain pose graph, optimised by gtvo.posegraph
    edges = [(i, i + 1, gtsam.Pose2(*u), ODOMETRY_SIGMAS) for i, u in enumerate(raw)]
    edges += [(i, j, motion, LOOP_SIGMAS) for (i, j), motion in loop_edges.items()]
    loops_only = pg.optimize(pose_graph_2d(dead_reckoning, edges), solver="handrolled", init="file").graph
    R = loops_only.rotations
    loops_only_poses = np.c_[loops_only.translations, np.arctan2(R[:, 1, 0], R[:, 0, 0])]

    # 9. The library's joint calibration: steps 2-7 in one call (GPS-like position priors at every 4th pose
    #    instead of the scan matcher)
    priors = [PosePrior(i, tuple(truth[i]), (0.05, 0.05, 1.0)) for i in range(0, len(truth), 4)]
    closures = [LoopClosure(i, j, (m.x(), m.y(), m.theta()), tuple(LOOP_SIGMAS)) for (i, j), m in loop_edges.items()]
    library = joint_calibration(raw, ODOMETRY_SIGMAS, priors, closures)

    # 10. Position errors against the truth (RMS, m)
    for name, estimate in (("dead reckoning", dead_reckoning), ("pose graph, loops only", loops_only_poses),
                           ("pose graph + calibration", poses), ("joint_calibration", library.poses)):
        print(f"{name:<25} {position_rmse(estimate, truth, align=False):.3f} m")


if __name__ == "__main__":
    main()
