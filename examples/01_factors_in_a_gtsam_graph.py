"""
gtvo's factors in a plain GTSAM graph: one HostPointsFactor (a keyframe's points seen in a second
frame, their inverse depths eliminated inside the factor) and StereoFactors (one inverse depth
each, from the left-right pair), with keys of our own, optimised by GTSAM's Levenberg-Marquardt.

The images are two frames of gtvo's synthetic stereo sequence, which knows its exact poses and
depths, so the script can print how far the estimates are from the truth.
Run from the checkout's root: python examples/01_factors_in_a_gtsam_graph.py
"""

import gtsam
import numpy as np
from gtsam.symbol_shorthand import D, X  # our own keys: X(i) poses T_world_cam, D(j) inverse depths

from factors import GradientImage, HostPointsFactor, StereoFactor
from gtvo.datasets.synthetic import make_synthetic_sequence


def strongest_pixels(gradient, cell=16, threshold=8.0):
    """(rows, cols) of the strongest pixel of every ``cell`` x ``cell`` block whose gradient exceeds ``threshold``."""
    h, w = gradient.shape[0] // cell, gradient.shape[1] // cell
    blocks = gradient[:h * cell, :w * cell].reshape(h, cell, w, cell).transpose(0, 2, 1, 3).reshape(h * w, -1)
    block = np.nonzero(blocks.max(axis=1) > threshold)[0]
    best = np.argmax(blocks[block], axis=1)
    return block // w * cell + best // cell, block % w * cell + best % cell


def main():
    """Main runner."""
    # 1. Two stereo frames with exact ground truth: the second 0.15 m ahead of the first
    seq = make_synthetic_sequence(n_frames=2, noise_sigma=1.0)
    camera, baseline = seq.camera.left, seq.camera.baseline
    host, target = seq.frame(0), seq.frame(1)
    true_depth = seq.true_depth(0)
    T_true = gtsam.Pose3(np.linalg.inv(seq.gt_poses[0]) @ seq.gt_poses[1])

    # 2. The points: well-textured pixels of the host's left image, their inverse depths 10 % off
    host_left, host_right = GradientImage(host.left), GradientImage(host.right)
    g_rows, g_cols = np.gradient(host.left.astype(float))
    rows, cols = strongest_pixels(np.hypot(g_rows, g_cols) * seq.interior_mask(0, margin=4))
    pixels = np.c_[cols, rows].astype(float)
    d_true = 1.0 / true_depth[rows, cols]
    d_init = d_true * np.random.default_rng(0).uniform(0.9, 1.1, d_true.size)

    # 3. Create a factor graph container and add factors to it
    graph = gtsam.NonlinearFactorGraph()
    # 3a. A prior fixes the first pose (the gauge)
    graph.add(gtsam.PriorFactorPose3(X(0), gtsam.Pose3(), gtsam.noiseModel.Isotropic.Sigma(6, 1e-6)))
    # 3b. One HostPointsFactor: the host's points in the target (photometric) and in the host's
    #     right image (stereo); the depths live inside it, so GTSAM sees only X(0) and X(1)
    host_factor = HostPointsFactor(X(0), [X(1)], camera, pixels, d_init, host_left, [GradientImage(target.left)],
                                   inverse_depth_variance=1e-2, right_image=host_right, baseline=baseline)
    graph.add(host_factor)
    # 3c. StereoFactors: the five points with the strongest horizontal gradient (the direction the
    #     stereo residual sees) again, each inverse depth a variable D(j) of the graph, with a weak prior
    stereo_points = np.argsort(np.abs(g_cols[rows, cols]))[-5:]
    for j, n in enumerate(stereo_points):
        graph.add(StereoFactor(D(j), None, camera, baseline, pixels[n], host_left, host_right,
                               inverse_depth_variance=1e-2))
        graph.add(gtsam.PriorFactorDouble(D(j), d_init[n], gtsam.noiseModel.Isotropic.Sigma(1, 0.1)))

    # 4. Initial estimates: the second pose at the first (no motion), the depths as measured
    initial = gtsam.Values()
    initial.insert(X(0), gtsam.Pose3())
    initial.insert(X(1), gtsam.Pose3())
    for j, n in enumerate(stereo_points):
        initial.insert(D(j), d_init[n])

    # 5. Optimise with Levenberg-Marquardt
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(50)
    optimizer = gtsam.LevenbergMarquardtOptimizer(graph, initial, params)
    result = optimizer.optimize()
    print(f"error {graph.error(initial):.1f} -> {graph.error(result):.1f} in {optimizer.iterations()} iterations")

    # 6. Compare with the truth: the relative pose, then the inverse depths
    T_est = result.atPose3(X(0)).between(result.atPose3(X(1)))
    print(f"translation true  {np.round(T_true.translation(), 4)}")
    print(f"translation found {np.round(T_est.translation(), 4)}")
    print(f"translation error {np.linalg.norm(T_est.translation() - T_true.translation()) * 1000:.1f} mm")
    d_host = host_factor.commit(result)  # the depths GTSAM's last step implies, kept in the factor
    print(f"HostPointsFactor depths: mean error {100 * np.mean(np.abs(d_host / d_true - 1)):.1f} % "
          f"(initial {100 * np.mean(np.abs(d_init / d_true - 1)):.1f} %, {d_true.size} points)")
    d_stereo = np.array([result.atDouble(D(j)) for j in range(5)])
    d_true, d_init = d_true[stereo_points], d_init[stereo_points]
    print(f"StereoFactor depths: mean error {100 * np.mean(np.abs(d_stereo / d_true - 1)):.1f} % "
          f"(initial {100 * np.mean(np.abs(d_init / d_true - 1)):.1f} %)")


if __name__ == "__main__":
    main()
