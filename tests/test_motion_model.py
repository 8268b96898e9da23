"""Kalman filter, R_t, RTS smoother, the factor-graph twin, and the planar pose conversions."""

from __future__ import annotations

import numpy as np
import pytest

from gtvo.errors import InputError
from gtvo.motion.graph import build_motion_graph, solve_motion_graph
from gtvo.motion.model import (
    POSE_MEASUREMENT_MATRIX,
    ConstantAccelerationFilter,
    MotionNoiseConfig,
    T_world_cam_from_planar_pose,
    filter_sequence,
    noise_gain,
    planar_pose_from_T_world_cam,
    predict,
    process_noise,
    rts_smooth,
    transition_matrix,
    update,
    wrap_angle,
)

NOISE = MotionNoiseConfig(accel_sigmas=(0.8, 1.2, 0.3), measurement_sigmas=(0.1, 0.15, 0.02))


def _trajectory(rng: np.random.Generator, n: int, theta0: float = 0.3) -> tuple[np.ndarray, np.ndarray]:
    """Noisy (X, Z, theta) of a car-like path with uneven time steps, theta far from +-pi."""
    times = np.cumsum(rng.uniform(0.05, 0.15, n))
    theta = theta0 + 0.3 * np.sin(times)
    speed = 5.0
    X = np.cumsum(speed * np.sin(theta) * np.gradient(times))
    Z = np.cumsum(speed * np.cos(theta) * np.gradient(times))
    z = np.column_stack([X, Z, theta]) + rng.normal(0, 1, (n, 3)) * np.asarray(NOISE.measurement_sigmas)
    return z, times


def _prior(z0: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    mean = np.array([z0[0] + 0.2, 1.0, z0[1] - 0.1, 4.0, z0[2], 0.0])
    cov = np.diag([0.5, 2.0, 0.5, 2.0, 0.1, 0.5]) ** 2
    cov[0, 2] = cov[2, 0] = 0.01  # some correlation
    return mean, cov


def test_process_noise_is_G_G_transpose_and_last_entry_uses_k3():
    T, k1, k2, k3 = 0.1, 0.7, 1.3, 0.4
    R = process_noise(T, k1, k2, k3)
    for axis, k in enumerate((k1, k2, k3)):
        block = R[2 * axis:2 * axis + 2, 2 * axis:2 * axis + 2]
        expected = np.array([[T**4 / 4, T**3 / 2], [T**3 / 2, T**2]]) * k**2
        np.testing.assert_allclose(block, expected, rtol=1e-14)
    assert R[5, 5] == pytest.approx(T**2 * k3**2, rel=1e-14)
    assert R[5, 5] != pytest.approx(T**2 * k2**2)  # the notes' typo would give this
    # R_t is the covariance of G a: check by sampling the accelerations (statistical, loose).
    rng = np.random.default_rng(0)
    a = rng.normal(0, 1, (400000, 3)) * [k1, k2, k3]
    e = a @ noise_gain(T).T
    np.testing.assert_allclose(np.cov(e.T), R, atol=3e-3 * np.abs(R).max())
    # zero off-axis coupling and rank 3 (each 2x2 block is rank 1)
    assert np.linalg.matrix_rank(R, tol=1e-14) == 3


def test_update_with_identity_C_is_the_notes_algorithm_2():
    rng = np.random.default_rng(1)
    mean = rng.normal(size=6) * 0.1
    L = rng.normal(size=(6, 6))
    S = L @ L.T + np.eye(6)
    M = rng.normal(size=(6, 6))
    Q = M @ M.T + np.eye(6)
    zt = mean + rng.normal(size=6) * 0.1
    mu, cov = update(mean, S, zt, Q, C=np.eye(6))
    K = S @ np.linalg.inv(S + Q)
    np.testing.assert_allclose(mu, mean + K @ (zt - mean), atol=1e-12)
    np.testing.assert_allclose(cov, (np.eye(6) - K) @ S, atol=1e-12)


def test_update_wraps_the_angle_innovation():
    mean = np.array([0, 0, 0, 0, np.pi - 0.05, 0.0])
    cov = np.eye(6) * 0.1
    Q = np.diag([0.01, 0.01, 0.1])
    mu, _ = update(mean, cov, [0, 0, -np.pi + 0.05], Q)  # 0.1 rad further, across the cut
    # innovation is +0.1, so theta moves forward by 0.1 * 0.1 / (0.1 + 0.1) = 0.05: lands on pi
    assert wrap_angle(mu[4] - (np.pi - 0.05 + 0.05)) == pytest.approx(0.0, abs=1e-12)
    assert -np.pi < mu[4] <= np.pi
    mu2, _ = update(mean, cov, [0, 0, -np.pi + 0.25], Q)  # innovation +0.3 -> theta = pi + 0.1 wrapped
    assert mu2[4] == pytest.approx(-np.pi + 0.1, abs=1e-12)
    # the same measurement expressed without the wrap gives the same result
    mu3, _ = update(mean, cov, [0, 0, np.pi + 0.25], Q)
    np.testing.assert_allclose(mu3, mu2, atol=1e-12)


def test_wrap_angle_range():
    a = np.array([-np.pi, np.pi, 3 * np.pi, -3 * np.pi + 1e-3, 0.0, 7.0])
    w = wrap_angle(a)
    assert np.all(w > -np.pi) and np.all(w <= np.pi)
    np.testing.assert_allclose(np.cos(w), np.cos(a), atol=1e-12)
    assert wrap_angle(-np.pi) == pytest.approx(np.pi)


def test_filter_final_state_equals_graph_marginal_and_rts_equals_graph_solution():
    rng = np.random.default_rng(2)
    z, times = _trajectory(rng, 40)
    prior_mean, prior_cov = _prior(z[0])
    res = filter_sequence(z, times, prior_mean, prior_cov, NOISE)
    graph = build_motion_graph(z, times, prior_mean, prior_cov, NOISE)
    n = len(times)
    means, covs = solve_motion_graph(graph, n, marginal_states=tuple(range(n)))
    np.testing.assert_allclose(res.means[-1], means[-1], rtol=0, atol=1e-9)
    np.testing.assert_allclose(res.covs[-1], covs[n - 1], rtol=0, atol=1e-9)
    sm, sc = rts_smooth(res)
    np.testing.assert_allclose(sm, means, rtol=0, atol=1e-9)
    for i in range(n):
        np.testing.assert_allclose(sc[i], covs[i], rtol=0, atol=1e-9)
    # the smoother differs from the filter before the last state (it does something)
    assert np.abs(sm[0] - res.means[0]).max() > 1e-3


def test_filter_reduces_error_against_truth():
    rng = np.random.default_rng(3)
    n = 200
    times = np.arange(n) * 0.1
    # truth from the model itself
    x = np.zeros((n, 6))
    x[0] = [0, 1.0, 0, 5.0, 0.1, 0.05]
    A = transition_matrix(0.1)
    G = noise_gain(0.1)
    for i in range(1, n):
        x[i] = A @ x[i - 1] + G @ (rng.normal(size=3) * NOISE.accel_sigmas)
    z = x[:, [0, 2, 4]] + rng.normal(size=(n, 3)) * NOISE.measurement_sigmas
    res = filter_sequence(z, times, x[0], np.eye(6) * 0.01, NOISE)
    raw = np.sqrt(np.mean((z[:, :2] - x[:, [0, 2]]) ** 2))
    filt = np.sqrt(np.mean((res.means[:, [0, 2]] - x[:, [0, 2]]) ** 2))
    sm, _ = rts_smooth(res)
    smooth = np.sqrt(np.mean((sm[:, [0, 2]] - x[:, [0, 2]]) ** 2))
    assert filt < 0.9 * raw and smooth < filt
    # normalised estimation error squared is consistent (mean about 6 over the states)
    err = res.means - x
    nees = np.einsum("ni,nij,nj->n", err, np.linalg.inv(res.covs), err)
    assert 3.0 < nees[20:].mean() < 10.0


def test_filter_handles_a_turn_across_pi():
    """A path whose heading crosses +-pi: the filter stays continuous (no 2 pi jump in the estimate)."""
    n = 60
    times = np.arange(n) * 0.1
    theta = wrap_angle(np.pi - 0.3 + 0.1 * np.arange(n))  # 1 rad/s, crosses pi at frame 3
    z = np.column_stack([np.zeros(n), np.zeros(n), theta])
    prior_mean = np.array([0, 0, 0, 0, theta[0], 1.0])
    res = filter_sequence(z, times, prior_mean, np.eye(6) * 0.01, NOISE)
    assert np.all(res.means[:, 4] > -np.pi) and np.all(res.means[:, 4] <= np.pi)
    np.testing.assert_allclose(wrap_angle(res.means[:, 4] - theta), 0.0, atol=5e-3)
    np.testing.assert_allclose(res.means[5:, 5], 1.0, atol=0.05)  # rate undisturbed by the wrap
    sm, _ = rts_smooth(res)
    np.testing.assert_allclose(wrap_angle(sm[:, 4] - theta), 0.0, atol=5e-3)


def test_stateful_filter_matches_sequence_and_predict_pose():
    rng = np.random.default_rng(4)
    z, times = _trajectory(rng, 15)
    f = ConstantAccelerationFilter(NOISE, initial_rate_sigmas=(2.0, 2.0, 0.5))
    f.initialize(z[0])
    prior_mean, prior_cov = f.mean, f.cov
    res = filter_sequence(z, times, prior_mean, prior_cov, NOISE)
    f.update(z[0])
    for i in range(1, len(times)):
        dt = times[i] - times[i - 1]
        guess = f.predict_pose(dt)
        pm, _ = predict(f.mean, f.cov, dt, NOISE.accel_sigmas)
        np.testing.assert_allclose(guess, pm[[0, 2, 4]], atol=1e-12)
        f.step(z[i], dt)
    np.testing.assert_allclose(f.mean, res.means[-1], atol=1e-12)
    np.testing.assert_allclose(f.cov, res.covs[-1], atol=1e-12)
    with pytest.raises(InputError):
        ConstantAccelerationFilter().predict_pose(0.1)


def test_planar_pose_round_trip_and_sign():
    # Camera turned right (optical axis towards +x) by 0.4 rad: theta = +0.4.
    T = T_world_cam_from_planar_pose(1.0, 2.0, 0.4)
    assert T[0, 2] > 0  # optical axis has a +x component
    assert planar_pose_from_T_world_cam(T) == pytest.approx((1.0, 2.0, 0.4))
    # with a pitched/rolled reference: y, pitch and roll kept, heading replaced
    import gtsam
    ref = gtsam.Pose3(gtsam.Rot3.Ypr(0.0, 0.0, 0.0).compose(gtsam.Rot3.RzRyRx(0.05, -0.7, 0.03)),
                      gtsam.Point3(3, -1.5, 4)).matrix()
    T2 = T_world_cam_from_planar_pose(-2.0, 5.0, 2.9, reference=ref)
    assert planar_pose_from_T_world_cam(T2) == pytest.approx((-2.0, 5.0, 2.9))
    assert T2[1, 3] == pytest.approx(-1.5)
    np.testing.assert_allclose(T2[:3, :3] @ T2[:3, :3].T, np.eye(3), atol=1e-12)
    assert T2[1, 2] == pytest.approx(ref[1, 2])  # optical axis elevation (pitch) kept
    with pytest.raises(InputError):
        planar_pose_from_T_world_cam(np.eye(3))


@pytest.mark.parametrize("bad", [
    dict(measurements=np.zeros((0, 3)), times=np.zeros(0)),
    dict(measurements=np.zeros((3, 2)), times=np.arange(3.0)),
    dict(measurements=np.array([[0, 0, 0], [np.nan, 0, 0]]), times=np.arange(2.0)),
    dict(measurements=np.zeros((3, 3)), times=np.array([0.0, 0.1, 0.1])),
])
def test_filter_bad_input(bad):
    with pytest.raises(InputError):
        filter_sequence(prior_mean=np.zeros(6), prior_cov=np.eye(6), **bad)


def test_bad_model_parameters():
    with pytest.raises(InputError):
        transition_matrix(0.0)
    with pytest.raises(InputError):
        MotionNoiseConfig(measurement_sigmas=(0.1, 0.0, 0.1))
    with pytest.raises(InputError):
        filter_sequence(np.zeros((2, 3)), [0, 1], np.zeros(6), -np.eye(6))
    assert POSE_MEASUREMENT_MATRIX.shape == (3, 6)


def test_process_factor_encodes_x_next_equals_A_x_prev_plus_G_a():
    """Unweighted residual W (x_next - A x_prev): soft rows = the accelerations a, hard rows = 0,
    and its Jacobians equal central differences of that residual (tolerance 1e-9)."""
    import gtsam

    from gtvo.core.keys import motion_state_key as state_key
    from factors.motion import process_factor, process_row_map

    dt, k = 0.13, np.array([0.8, 1.2, 0.3])
    f = process_factor(state_key(0), state_key(1), dt, k)
    rng = np.random.default_rng(7)
    x_prev = rng.normal(size=6)
    a = rng.normal(size=3)
    x_next = transition_matrix(dt) @ x_prev + noise_gain(dt) @ a
    vv = gtsam.VectorValues()
    vv.insert(state_key(0), x_prev)
    vv.insert(state_key(1), x_next)
    r = np.asarray(f.unweighted_error(vv))
    np.testing.assert_allclose(r[0::2], a, atol=1e-12)      # soft rows: the acceleration
    np.testing.assert_allclose(r[1::2], 0.0, atol=1e-12)    # hard rows: satisfied exactly
    assert f.isConstrained()
    sig = np.asarray(f.get_model().sigmas())
    np.testing.assert_allclose(sig[0::2], k)
    np.testing.assert_allclose(sig[1::2], 0.0)

    def residual(xp, xn):
        return process_row_map(dt) @ (xn - transition_matrix(dt) @ xp)

    A_unw, _ = f.jacobianUnweighted()
    eps = 1e-6
    num = np.zeros((6, 12))
    for j in range(12):
        d = np.zeros(12)
        d[j] = eps
        num[:, j] = (residual(x_prev + d[:6], x_next + d[6:]) - residual(x_prev - d[:6], x_next - d[6:])) / (2 * eps)
    np.testing.assert_allclose(A_unw, num, atol=1e-9)


def test_measurement_and_prior_factors():
    import gtsam

    from gtvo.core.keys import motion_state_key as state_key
    from factors.motion import pose_measurement_factor, state_prior_factor

    rng = np.random.default_rng(8)
    x = rng.normal(size=6)
    vv = gtsam.VectorValues()
    vv.insert(state_key(3), x)
    z = rng.normal(size=3)
    m = pose_measurement_factor(state_key(3), z, NOISE.measurement_sigmas)
    np.testing.assert_allclose(np.asarray(m.unweighted_error(vv)), x[[0, 2, 4]] - z, atol=1e-12)
    mean, cov = _prior(np.zeros(3))
    p = state_prior_factor(state_key(3), mean, cov)
    # whitened squared error = Mahalanobis distance under cov
    e = x - mean
    assert 2 * p.error(vv) == pytest.approx(e @ np.linalg.solve(cov, e), rel=1e-12)
