"""Pose covariances (issue 23, items 3 and 5): the window's two solvers and the fixed-lag smoother
agree, they shrink with more points, the run writes them (covariances.npz, report.json, ellipses)
and `--no-covariances` writes none; `gtvo posegraph --covariances` equals gtsam.Marginals."""

from __future__ import annotations

import argparse
import copy
import json

import gtsam
import numpy as np
import pytest

import gtvo.posegraph as pg
from gtvo.config import FrontendConfig, KeyframeConfig, OdometryConfig
from gtvo.datasets.synthetic import make_synthetic_sequence
from gtvo.errors import InputError
from gtvo.io.covariances import TANGENT_FRAME, TANGENT_ORDER, read_covariances, sigmas
from gtvo.io.plots import plane_matrix, project_to_plane
from gtvo.odometry import VisualOdometry
from gtvo.posegraph.graph import PoseGraph
from gtvo.window import SlidingWindowOptimizer, WindowConfig, solve_gtsam, solve_handrolled
from tests.test_window import _keyframes
from tests._window_problem import problem


@pytest.fixture(scope="module")
def seq():
    return make_synthetic_sequence(10, width=240, height=180, step_m=0.1)


def _rel(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.linalg.norm(a - b) / np.linalg.norm(b))


@pytest.mark.slow
def test_gtsam_marginals_equal_the_inverse_reduced_hessian(seq):
    """One window (5 keyframes, gauge prior), solved to convergence by each solver: gtsam.Marginals
    on the GTSAM path and the inverse of the hand-rolled reduced Hessian agree.

    Measured: 3e-5 relative (Frobenius) per keyframe with Huber; tolerance 1e-3. The oldest
    keyframe's covariance is the gauge prior's (sigma 1e-6).
    """
    cam = seq.camera
    kfs = _keyframes(seq, [0, 2, 4, 6, 8], perturb=(0.002, 0.006), timed=True)
    cfg = WindowConfig(max_iterations=40, relative_tolerance=1e-12)
    ra = solve_gtsam(problem(cam.left, cam.baseline, copy.deepcopy(kfs), cfg))
    rb = solve_handrolled(problem(cam.left, cam.baseline, copy.deepcopy(kfs), cfg))
    assert sorted(ra.covariances) == sorted(rb.covariances) == [0, 2, 4, 6, 8]
    assert ra.covariance_seconds > 0 and rb.covariance_seconds > 0
    for i, Pa in ra.covariances.items():
        Pb = rb.covariances[i]
        assert Pa.shape == (6, 6) and np.allclose(Pa, Pa.T)
        assert np.linalg.eigvalsh(Pa).min() > 0
        assert _rel(Pa, Pb) < 1e-3
    assert np.sqrt(np.diag(ra.covariances[0])) == pytest.approx(np.full(6, cfg.gauge_sigma), rel=1e-3)
    assert np.sqrt(np.trace(ra.covariances[8][3:, 3:])) > 1e-4  # a real uncertainty, far above the gauge


def test_covariance_shrinks_with_more_points(seq):
    """About 5x the points per keyframe: the position sigma falls by about sqrt(5).

    Measured (4 keyframes, ~50 vs ~260 points): 6.0 mm -> 2.9 mm (ratio 0.48); asserted < 0.65.
    """
    cam = seq.camera
    sig = {}
    for pts in (60, 300):
        r = solve_handrolled(problem(cam.left, cam.baseline, _keyframes(seq, [0, 2, 4, 6], points=pts),
                             WindowConfig(max_iterations=5)))
        sig[pts] = np.array([np.sqrt(np.trace(r.covariances[i][3:, 3:])) for i in (2, 4, 6)])
    assert np.all(sig[300] < 0.65 * sig[60])


def test_window_keeps_each_keyframes_last_covariance_and_backends_agree(seq):
    """5 keyframes through a window of 3 (two marginalisations): every keyframe keeps the covariance
    of the last window it was in; the hand-rolled path and the fixed-lag smoother's iSAM2 marginals
    agree with gtsam.Marginals on the LM path.

    Measured: hand-rolled 2.4e-4, fixed-lag 3.5e-3 relative (Frobenius); tolerances 2e-3, 2e-2.
    """
    cam = seq.camera
    kfs = _keyframes(seq, [0, 2, 4, 6, 8], perturb=(0.002, 0.006), points=200, timed=True)
    covs, last = {}, {}
    for solver, backend in (("gtsam", "lm"), ("handrolled", "lm"), ("gtsam", "fixed_lag")):
        w = SlidingWindowOptimizer(cam.left, cam.baseline, WindowConfig(size=3, max_iterations=10, backend=backend))
        seen = {}
        for kf in copy.deepcopy(kfs):
            w.add_keyframe(kf)
            res = w.optimize(solver)
            if res is not None:
                seen.update({i: P.copy() for i, P in res.covariances.items()})
        assert sorted(w.covariances) == [0, 2, 4, 6, 8]
        covs[solver, backend], last[solver, backend] = w.covariances, seen
    ref = covs["gtsam", "lm"]
    for i in (2, 4, 6, 8):
        assert np.array_equal(ref[i], last["gtsam", "lm"][i])  # from its last window
        assert _rel(covs["handrolled", "lm"][i], ref[i]) < 2e-3
        assert _rel(covs["gtsam", "fixed_lag"][i], ref[i]) < 2e-2
    # a keyframe that left after the first window keeps that window's covariance, not a later one
    assert np.sqrt(np.trace(ref[0][3:, 3:])) < 1e-5


@pytest.mark.parametrize("solver", ["gtsam", "handrolled"])
def test_covariances_add_no_residual_pass_and_change_nothing(seq, monkeypatch, solver):
    """With covariances the solvers evaluate the photometric residuals exactly as often as without
    (the covariance reuses the last cost pass's Jacobians) and end at the same poses and depths."""
    import factors.host_points as host_points  # noqa: PLC0415

    cam = seq.camera
    kfs = _keyframes(seq, [0, 2, 4], perturb=(0.002, 0.006), points=150)
    solve = {"gtsam": solve_gtsam, "handrolled": solve_handrolled}[solver]
    real = host_points.photometric_residuals
    ends = {}
    for on in (False, True):
        calls = []
        monkeypatch.setattr(host_points, "photometric_residuals", lambda *a, **k: calls.append(1) or real(*a, **k))
        ks = copy.deepcopy(kfs)
        res = solve(problem(cam.left, cam.baseline, ks, WindowConfig(max_iterations=4, covariances=on)))
        assert (res.covariances is not None) == on
        ends[on] = (len(calls), ks)
    assert ends[True][0] == ends[False][0]
    for a, b in zip(ends[True][1], ends[False][1]):
        assert np.array_equal(a.pose.matrix(), b.pose.matrix())
        assert np.array_equal(a.inverse_depth, b.inverse_depth)


def test_covariances_off_cost_nothing(seq):
    cam = seq.camera
    kfs = _keyframes(seq, [0, 2, 4], points=150)
    w = SlidingWindowOptimizer(cam.left, cam.baseline, WindowConfig(max_iterations=3, covariances=False))
    for kf in kfs:
        w.add_keyframe(kf)
    for solver in ("gtsam", "handrolled"):
        res = w.optimize(solver)
        assert res.covariances is None and res.covariance_seconds == 0.0
    assert w.covariances == {}


def test_visual_odometry_covariance_api(seq):
    vo = VisualOdometry(seq.camera, OdometryConfig(mode="window", frontend=FrontendConfig(points_per_keyframe=150),
                                                   keyframes=KeyframeConfig(max_motion=0.02)))
    for i in range(4):
        vo.process(seq.frame(i))
    assert len(vo.keyframes) >= 2
    for kf in vo.keyframes:
        P = vo.covariance(kf)
        assert P is not None and P.shape == (6, 6)
        assert np.array_equal(P, vo.covariance(kf.index))
        assert np.allclose(vo.covariance(kf, inflation=4.0), 4.0 * P)
    with pytest.raises(InputError):
        vo.covariance(vo.keyframes[0], inflation=0.0)
    from gtvo.pipeline import keyframe_covariances  # noqa: PLC0415

    cov = keyframe_covariances(vo, inflation=2.0)
    assert list(cov.frame_index) == [kf.index for kf in vo.keyframes] and cov.inflation == 2.0
    assert np.allclose(cov.covariance[-1], 2.0 * vo.covariance(vo.keyframes[-1]))
    non_kf = [e.index for e in vo.estimates if not e.is_keyframe]
    if non_kf:
        with pytest.raises(InputError):
            vo.covariance(non_kf[0])
    track = VisualOdometry(seq.camera, OdometryConfig(mode="track", frontend=FrontendConfig(points_per_keyframe=150)))
    track.process(seq.frame(0))
    assert track.covariance(0) is None


@pytest.mark.slow
def test_run_writes_covariances_and_report(tmp_path):
    """`gtvo run` on a written synthetic sequence: covariances.npz with one covariance per keyframe,
    its metadata, the report's summary (recomputed from the file); `--no-covariances` writes none."""
    from gtvo import cli  # noqa: PLC0415

    data = tmp_path / "syn"
    assert cli.main(["synthetic", "--out", str(data), "--frames", "12", "--width", "160", "--height", "120",
                     "--noise-sigma", "2", "--no-progress"]) == 0
    out = tmp_path / "out"
    assert cli.main(["run", str(data), "--out", str(out), "--no-progress", "--points", "150"]) == 0
    report = json.loads((out / "report.json").read_text())
    cov = read_covariances(out / "covariances.npz")
    with np.load(out / "covariances.npz") as z:
        assert str(z["tangent_order"]) == TANGENT_ORDER and str(z["frame"]) == TANGENT_FRAME
    assert report["covariances"] == "written" and report["covariance_keyframes"] == len(cov) == report["keyframes"]
    assert np.all(np.diff(cov.frame_index) > 0) and cov.frame_index[0] == 0
    tum = np.loadtxt(out / "trajectory.tum")
    assert np.allclose(cov.timestamp, tum[cov.frame_index, 0])  # every frame is in trajectory.tum, in order
    pos, rot = sigmas(cov.covariance[1:])
    assert report["covariance_position_sigma_m_median"] == pytest.approx(np.median(pos))
    assert report["covariance_position_sigma_m_max"] == pytest.approx(pos.max())
    assert report["covariance_rotation_sigma_deg_max"] == pytest.approx(rot.max())
    assert 0 < report["covariance_seconds"] and 1e-5 < report["covariance_position_sigma_m_median"] < 0.1
    off = tmp_path / "off"
    assert cli.main(["run", str(data), "--out", str(off), "--no-progress", "--points", "150", "--no-covariances"]) == 0
    report_off = json.loads((off / "report.json").read_text())
    assert not (off / "covariances.npz").exists()
    assert report_off["covariances"].startswith("not computed") and report_off["covariance_seconds"] == 0.0
    assert "covariance_position_sigma_m_median" not in report_off


def test_hessian_marginals_and_undetermined_poses():
    """The pose blocks of H^-1 (badly scaled H: a gauge-like 1e12 entry); a singular H gives NaN,
    which the report leaves out of its sigmas and counts."""
    from gtvo.io.covariances import KeyframeCovariances, covariance_summary  # noqa: PLC0415
    from gtvo.window.covariance import marginals_of_hessian  # noqa: PLC0415

    rng = np.random.default_rng(3)
    A = rng.normal(size=(40, 16))
    H = A.T @ A
    H[:8, :8] += 1e12 * np.eye(8)
    C = np.linalg.inv(H)
    out = marginals_of_hessian(H, [5, 9])
    assert _rel(out[5], C[:6, :6]) < 1e-6 and _rel(out[9], C[8:14, 8:14]) < 1e-6
    H[:, 12] = H[12, :] = 0.0  # a direction with no information
    assert all(np.isnan(P).all() for P in marginals_of_hessian(H, [5, 9]).values())
    P = np.stack([np.eye(6) * 1e-12, np.diag([1e-4] * 3 + [4e-4] * 3), np.full((6, 6), np.nan)])
    rep = covariance_summary(KeyframeCovariances([0, 3, 7], [0.0, 0.3, 0.7], P, "test"))
    assert rep["covariance_undetermined"] == 1 and rep["covariance_keyframes"] == 3
    assert rep["covariance_position_sigma_m_max"] == pytest.approx(np.sqrt(12e-4))
    assert rep["covariance_rotation_sigma_deg_median"] == pytest.approx(np.degrees(np.sqrt(3e-4)))


@pytest.mark.parametrize("plane", ["xz", "pca"])
def test_plane_matrix_is_the_projection(plane):
    rng = np.random.default_rng(1)
    P = rng.normal(size=(10, 3)) * [3.0, 0.2, 5.0]
    A = plane_matrix(plane, P)
    uv, _, _ = project_to_plane(P, plane, P)
    assert np.allclose(uv[1:] - uv[0], (P[1:] - P[0]) @ A.T)


def _small_graph(rng: np.random.Generator) -> PoseGraph:
    """A 3-D chain of 6 nodes with one loop edge, noisy measurements, full information matrices."""
    n = 6
    true = [gtsam.Pose3(gtsam.Rot3.Yaw(0.3 * k), np.array([k, 0.1 * k, 0.0])) for k in range(n)]
    edges = [(k, k + 1) for k in range(n - 1)] + [(0, n - 1)]
    Rm, tm, info = [], [], []
    for i, j in edges:
        Z = true[i].between(true[j]).retract(rng.normal(size=6) * 0.01)
        Rm.append(Z.rotation().matrix())
        tm.append(Z.translation())
        A = rng.normal(size=(6, 6)) * 3
        info.append(A @ A.T + 100 * np.eye(6))
    R = np.stack([p.rotation().matrix() for p in true])
    t = np.stack([p.translation() for p in true])
    return PoseGraph(3, np.arange(n) + 10, R, t, True, np.array([e[0] for e in edges]),
                     np.array([e[1] for e in edges]), np.stack(Rm), np.stack(tm), np.stack(info))


@pytest.mark.parametrize("solver", ["gtsam", "handrolled"])
def test_posegraph_covariances_equal_gtsam_marginals(tmp_path, solver):
    """`gtvo posegraph --covariances` against gtsam.Marginals of the same graph built here."""
    from gtvo.commands import posegraph as cmd  # noqa: PLC0415

    graph = _small_graph(np.random.default_rng(0))
    src = tmp_path / "g.g2o"
    pg.write_g2o(src, graph)
    parser = argparse.ArgumentParser()
    cmd.register(parser.add_subparsers())
    out_g2o, npz = tmp_path / "opt.g2o", tmp_path / "cov.npz"
    args = parser.parse_args(["posegraph", str(src), "--solver", solver, "--json", "--out", str(out_g2o),
                              "--covariances", str(npz)])
    assert args.func(args) == 0
    opt = pg.read(out_g2o)
    fg = gtsam.NonlinearFactorGraph()
    values = gtsam.Values()
    for k in range(opt.num_poses):
        values.insert(k, gtsam.Pose3(gtsam.Rot3(opt.rotations[k]), opt.translations[k]))
    for e in range(graph.num_edges):
        fg.add(gtsam.BetweenFactorPose3(int(graph.edge_i[e]), int(graph.edge_j[e]),
                                        gtsam.Pose3(gtsam.Rot3(graph.meas_rotations[e]), graph.meas_translations[e]),
                                        gtsam.noiseModel.Gaussian.Information(graph.information[e])))
    fg.add(gtsam.PriorFactorPose3(0, values.atPose3(0), gtsam.noiseModel.Isotropic.Sigma(6, 1e-6)))
    marginals = gtsam.Marginals(fg, values)
    with np.load(npz) as z:
        assert list(z["node_id"]) == list(range(10, 16))
        C = z["covariance"]
        assert str(z["tangent_order"]).startswith("rx, ry, rz, tx, ty, tz")
    assert C.shape == (6, 6, 6)
    for k in range(1, opt.num_poses):
        ref = marginals.marginalCovariance(k)
        assert _rel(C[k], ref) < 1e-4
    # the far end of the chain is less certain than the node next to the anchor
    assert np.trace(C[3]) > np.trace(C[1])


def test_posegraph_covariances_2d_against_gtsams_reader(shared_data, tmp_path):
    """A 2-D file: the written marginals equal gtsam.Marginals of the graph GTSAM's own g2o reader
    builds, at the optimised poses (node ids as keys, prior on the first node)."""
    from gtvo import cli  # noqa: PLC0415

    path = shared_data / "pose_graphs" / "gtsam" / "pose2example.txt"
    out, npz = tmp_path / "opt.g2o", tmp_path / "cov.npz"
    assert cli.main(["posegraph", str(path), "--json", "--out", str(out), "--covariances", str(npz)]) == 0
    fg, _ = gtsam.readG2o(str(path), False)
    _, values = gtsam.readG2o(str(out), False)
    with np.load(npz) as z:
        ids, C = list(z["node_id"]), z["covariance"]
    fg.add(gtsam.PriorFactorPose2(int(ids[0]), values.atPose2(int(ids[0])), gtsam.noiseModel.Isotropic.Sigma(3, 1e-6)))
    marginals = gtsam.Marginals(fg, values)
    assert C.shape == (len(ids), 3, 3)
    for k in range(1, len(ids)):
        assert _rel(C[k], marginals.marginalCovariance(int(ids[k]))) < 1e-4


def test_trajectory_ellipses_are_the_projected_95_percent_ellipses():
    """An elongated position covariance on the xz plane: the drawn ellipse has the 95 % half axes
    sqrt(5.991 * eigenvalue) times the gain the legend names, along the covariance's main axis."""
    from gtvo.io.plots import _draw_ellipses, _new_figure  # noqa: PLC0415

    path = np.c_[np.linspace(0, 10, 11), np.zeros(11), np.linspace(0, 20, 11)]
    R = gtsam.Rot3.Ry(0.5).matrix()  # main axis in the xz plane, 0.5 rad from x towards -z
    P = R @ np.diag([4e-4, 1e-6, 1e-4]) @ R.T
    fig = _new_figure((4, 4))
    ax = fig.add_subplot(1, 1, 1)
    _draw_ellipses(ax, path[5:6], P[None], "xz", path)
    (e,) = ax.patches
    gain = float(e.get_label().split("x")[-1])
    assert gain in (10.0, 20.0, 50.0) and 2 * gain * np.sqrt(5.991 * 4e-4) <= np.ptp(path[:, 2]) / 20
    assert e.width == pytest.approx(2 * gain * np.sqrt(5.991 * 4e-4), rel=1e-3)
    assert e.height == pytest.approx(2 * gain * np.sqrt(5.991 * 1e-4), rel=1e-3)
    assert np.cos(np.radians(e.angle) + 0.5) == pytest.approx(1.0, abs=1e-6) or \
        np.cos(np.radians(e.angle) + 0.5) == pytest.approx(-1.0, abs=1e-6)
