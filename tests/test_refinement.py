"""The whole-log refinement (issue 32, gtvo.refinement): its graph, both solvers on it, loop edges
rejected by the refined cost, an LM that cannot improve, and a run with it (report, CLI, Ctrl-C)."""

from __future__ import annotations

import copy
import dataclasses
import json
import subprocess
import sys

import gtsam
import numpy as np
import pytest

from factors.params import PhotometricConfig
from gtvo.datasets.synthetic import make_synthetic_sequence, write_sequence_kitti
from gtvo.loops.closure_graph import LoopEdge
from gtvo.refinement import RefineConfig, covisible_targets
from gtvo.refinement.graph import candidate_targets, loop_chi2, scale_change, window_candidates, window_edges
from gtvo.window import TargetChoice, WindowConfig, WindowResult, visible_targets
from tests.test_window import _keyframes
from tests._window_problem import problem, refine

NO_HUBER = PhotometricConfig(huber_k=None)


@pytest.fixture(scope="module")
def seq():
    return make_synthetic_sequence(10, width=240, height=180, step_m=0.1)


@pytest.fixture(scope="module")
def keyframes(seq):
    return _keyframes(seq, [0, 2, 4, 6, 8], perturb=(0.002, 0.006), timed=True)


def _edge(seq, i, j, dt=(0.0, 0.0, 0.0), sigma_t=0.01):
    T = np.linalg.inv(seq.gt_poses[i]) @ seq.gt_poses[j]
    T[:3, 3] += dt
    return LoopEdge(i, j, T, np.diag([1 / 0.002**2] * 3 + [1 / sigma_t**2] * 3))


def test_visible_targets_takes_candidates_and_a_cap(seq, keyframes):
    cam, cfg = seq.camera.left, WindowConfig()
    every = visible_targets(cam, keyframes, cfg)
    assert visible_targets(cam, keyframes, cfg, TargetChoice(candidates=[list(range(5))] * 5)) == every
    only = visible_targets(cam, keyframes, cfg, TargetChoice(candidates=[[1], [0], [], [], []]))
    assert only == [[1] if 1 in every[0] else [], [0] if 0 in every[1] else [], [], [], []]
    capped = visible_targets(cam, keyframes, cfg, TargetChoice(max_targets=1))
    assert all(len(c) <= 1 and set(c) <= set(e) for c, e in zip(capped, every))
    assert capped[2] and abs(capped[2][0] - 2) == 1  # of equals in count, a neighbour sees most


def test_scale_change_is_the_points_magnification(seq, keyframes):
    cam = seq.camera.left
    host = keyframes[0]
    assert scale_change(cam, host, host) == pytest.approx(0.0, abs=1e-12)
    z = 1.0 / host.inverse_depth
    forward = dataclasses.replace(host, pose=host.pose.compose(gtsam.Pose3(gtsam.Rot3(), [0, 0, 0.5 * z.min()])))
    assert scale_change(cam, host, forward) == pytest.approx(np.median(np.log(z / (z - 0.5 * z.min()))), rel=1e-9)
    behind = dataclasses.replace(host, pose=host.pose.compose(gtsam.Pose3(gtsam.Rot3(), [0, 0, 10 * z.max()])))
    assert scale_change(cam, host, behind) == np.inf


def test_candidates_include_a_revisit_far_in_time(keyframes):
    revisit = dataclasses.replace(keyframes[0], index=99)  # the first place again, at the end of the log
    kfs = list(keyframes) + [revisit]
    cand = candidate_targets(kfs, max_targets=1)
    assert 5 in cand[0] and 1 in cand[0]  # the revisit (near in space) and the next keyframe
    assert 0 in cand[5]


def test_window_candidates_are_the_window_span_and_a_revisit_only_across_a_loop(seq, keyframes):
    assert window_candidates(5, 1) == [[1], [0, 2], [1, 3], [2, 4], [3]]
    cam = seq.camera.left
    kfs = list(keyframes) + [dataclasses.replace(keyframes[0], index=99)]  # the first place again, at the end
    cfg = WindowConfig(size=3)
    six = RefineConfig(max_targets=6, max_scale_change=None)
    window = covisible_targets(cam, kfs, cfg, six)  # the default: the window's span, 2 on each side
    space = covisible_targets(cam, kfs, cfg, dataclasses.replace(six, candidates="space"))
    assert 5 in space[0] and 5 not in window[0] and 0 not in window[5]
    assert all(abs(t - h) <= 2 for h, ts in enumerate(window) for t in ts) and all(window)
    looped = covisible_targets(cam, kfs, cfg, six, [(0, 5)])  # across a verified loop: compared
    assert 5 in looped[0] and 0 in looped[5]
    assert window_candidates(12, 1, [(1, 10)])[1] == [0, 2, 9, 10, 11]  # the loop's neighbourhoods, both ways
    assert window_candidates(12, 1, [(1, 10)])[5] == [4, 6]


def test_window_edges_are_the_window_relative_poses_with_the_tracker_covariance(keyframes):
    covs = [1e-4 * np.eye(6), None, np.full((6, 6), np.nan), 4e-4 * np.eye(6)]
    edges = window_edges(keyframes, covs)
    assert [(e.i, e.j) for e in edges] == [(0, 2), (6, 8)]  # no covariance (or not finite): no edge
    np.testing.assert_allclose(edges[0].T_i_j, keyframes[0].pose.between(keyframes[1].pose).matrix(), atol=1e-12)
    np.testing.assert_allclose(edges[1].information, 2500.0 * np.eye(6))


def test_window_edges_hold_the_refined_keyframes_near_the_window_shape(seq, keyframes):
    cam = seq.camera
    covs = [1e-10 * np.eye(6)] * (len(keyframes) - 1)  # the window's relative poses, all but certain
    cfg = RefineConfig(max_iterations=3, max_scale_change=None)
    held = refine(cam.left, cam.baseline, keyframes, WindowConfig(), cfg, odometry_covariances=covs)
    free = refine(cam.left, cam.baseline, keyframes, WindowConfig(),
                            dataclasses.replace(cfg, window_edges=False), odometry_covariances=covs)

    def moved(res):
        return max(np.abs(a.pose.between(b.pose).localCoordinates(ka.pose.between(kb.pose))).max()
                   for a, b, ka, kb in zip(keyframes, keyframes[1:], res.keyframes, res.keyframes[1:]))

    assert held.ran and free.ran
    assert moved(held) < 1e-3 and moved(free) > 1e-2  # measured 2e-4 and 2e-2


@pytest.mark.slow
def test_both_solvers_solve_the_same_whole_log_graph_with_a_loop_edge(seq, keyframes):
    """The refinement's graph (host factors over the covisible targets, priors, motion prior and
    a loop edge) solved by GTSAM's LM and by the hand-rolled LM: same cost, same poses (the
    window's own tolerances, tests/test_window.py)."""
    cam = seq.camera
    cfg = RefineConfig(max_iterations=40, relative_tolerance=1e-12, max_scale_change=None)
    edge = _edge(seq, 0, 8)
    out = {s: refine(cam.left, cam.baseline, keyframes, WindowConfig(), dataclasses.replace(cfg, solver=s),
                               loop_edges=[edge], photometric=NO_HUBER) for s in ("gtsam", "handrolled")}
    a, b = out["gtsam"], out["handrolled"]
    assert a.ran and b.ran and a.loop_edges == b.loop_edges == 1 and a.loop_edges_dropped == 0
    assert a.cost_before == pytest.approx(b.cost_before, rel=1e-9)  # the same graph
    assert a.cost_after < 0.5 * a.cost_before
    assert a.cost_after == pytest.approx(b.cost_after, rel=1e-4)
    for ka, kb in zip(a.keyframes, b.keyframes):
        assert np.abs(ka.pose.localCoordinates(kb.pose)).max() < 3e-5
    assert keyframes[1].pose.equals(copy.deepcopy(keyframes)[1].pose, 0)  # the input is not changed
    assert a.keyframes[1] is not keyframes[1]


@pytest.mark.slow
def test_a_loop_edge_the_refined_cost_rejects_is_dropped_and_counted(seq, keyframes):
    cam = seq.camera
    cfg = RefineConfig(max_iterations=10)
    good = refine(cam.left, cam.baseline, keyframes, WindowConfig(), cfg)
    bad = _edge(seq, 0, 8, dt=(0.4, 0.0, 0.0), sigma_t=0.1)  # 4 sigma off in one axis: chi-square 16 + the rest
    assert loop_chi2([bad], good.keyframes)[0] > cfg.loop_chi2
    res = refine(cam.left, cam.baseline, keyframes, WindowConfig(), cfg, loop_edges=[bad, _edge(seq, 2, 8)])
    assert res.ran and res.loop_edges_dropped == 1 and res.loop_edges == 1
    for ka, kb in zip(res.keyframes, good.keyframes):  # solved again without it: as if it never was
        assert np.linalg.norm(ka.pose.translation() - kb.pose.translation()) < 2e-3


@pytest.mark.parametrize("factor,reason", [(2.0, "LM diverged"), (1.0, "LM could not lower the cost")])
def test_an_lm_that_cannot_improve_keeps_the_window_answer(seq, keyframes, monkeypatch, factor, reason):
    import gtvo.refinement.solve as solve

    def no_better(problem):
        return WindowResult("gtsam", 10.0, 10.0 * factor, 3, 0.1, 1)

    monkeypatch.setattr(solve, "solve_gtsam", no_better)
    res = refine(seq.camera.left, seq.camera.baseline, keyframes, WindowConfig(), RefineConfig())
    assert not res.ran and res.reason.startswith(reason) and res.reason.endswith("the window's answer is kept")
    assert all(a is b for a, b in zip(res.keyframes, keyframes)) and res.covariances is None


def test_targets_over_the_whole_log_respect_the_cap_and_the_scale_change(seq, keyframes):
    cam = seq.camera.left
    free = covisible_targets(cam, keyframes, WindowConfig(), RefineConfig(max_targets=6, max_scale_change=None))
    assert free == visible_targets(cam, keyframes, WindowConfig())  # a small log: every pair is a candidate
    tight = covisible_targets(cam, keyframes, WindowConfig(), RefineConfig(max_targets=6, max_scale_change=1e-6))
    assert not any(tight)
    some = covisible_targets(cam, keyframes, WindowConfig(), RefineConfig(max_targets=6, max_scale_change=0.06))
    assert all(set(s) <= set(f) for s, f in zip(some, free)) and some != free and any(some)


# -- a run with the refinement ----------------------------------------------------------------

@pytest.fixture(scope="module")
def kitti_like(tmp_path_factory):
    d = tmp_path_factory.mktemp("refine") / "synthetic_kitti"
    write_sequence_kitti(make_synthetic_sequence(n_frames=10, noise_sigma=1.0, seed=3), d)
    return d


def _run(*args):
    return subprocess.run([sys.executable, "-m", "gtvo", "run", *map(str, args), "--no-progress"],
                          capture_output=True, text=True, timeout=600)


@pytest.mark.slow
def test_a_run_reports_its_refinement_and_no_refine_turns_it_off(kitti_like, tmp_path):
    r = _run(kitti_like, "--out", tmp_path / "on", "--refine")
    assert r.returncode == 0, r.stderr
    rep = json.loads((tmp_path / "on" / "report.json").read_text())
    block = rep["refine"]
    assert block["ran"] and block["reason"] is None and block["iterations"] >= 1
    assert block["cost_after"] < block["cost_before"] and block["keyframes"] == rep["keyframes"]
    assert block["window_ate_rmse_m"] is not None and rep["config"]["refine"]["enabled"] is True
    assert rep["covariance_source"] == "gtsam.Marginals of the whole-log refinement's graph"
    assert rep["covariance_keyframes"] == rep["keyframes"]
    (tmp_path / "c.yaml").write_text("refine: {enabled: true}\n")
    r = _run(kitti_like, "--out", tmp_path / "off", "--config", tmp_path / "c.yaml", "--no-refine")
    assert r.returncode == 0, r.stderr
    assert "refine" not in json.loads((tmp_path / "off" / "report.json").read_text())


def test_refine_with_track_mode_is_refused(kitti_like, tmp_path):
    r = _run(kitti_like, "--out", tmp_path / "x", "--refine", "--mode", "track")
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1 and "--refine needs --mode window" in r.stderr


@pytest.mark.slow
def test_ctrl_c_during_the_refinement_is_ctrl_c_everywhere(kitti_like, tmp_path, monkeypatch, capsys):
    """A KeyboardInterrupt inside the refinement's solver is the README's one rule for Ctrl-C:
    `gtvo run: interrupted`, exit 130, the earlier output set exactly as it was (before: exit 0 with
    window-only outputs replacing it)."""
    from gtvo import cli
    import gtvo.refinement.solve as solve

    out = tmp_path / "out"
    assert cli.main(["run", str(kitti_like), "--out", str(out), "--no-progress", "--max-frames", "4"]) == 0
    before = {p.name: p.read_bytes() for p in out.iterdir()}

    def interrupted(*a, **k):
        raise KeyboardInterrupt

    monkeypatch.setattr(solve, "solve_gtsam", interrupted)
    capsys.readouterr()
    assert cli.main(["run", str(kitti_like), "--out", str(out), "--no-progress", "--refine"]) == 130
    err = capsys.readouterr().err
    assert err.strip().splitlines()[-1] == "gtvo run: interrupted" and "window-only" not in err, err
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]  # no staging, no lock left


def test_lm_iteration_by_iteration_is_gtsam_own_loop(seq, keyframes):
    """``on_iteration`` runs GTSAM's LM one iteration at a time: the same iterations, cost and
    poses as ``optimize()`` (the window's path), bit for bit."""
    from gtvo.window import solve_gtsam

    cam = seq.camera
    a, b = copy.deepcopy(keyframes), copy.deepcopy(keyframes)
    cfg = WindowConfig(max_iterations=6)
    seen = []
    ra = solve_gtsam(problem(cam.left, cam.baseline, a, cfg))
    rb = solve_gtsam(problem(cam.left, cam.baseline, b, cfg, on_iteration=lambda it, cost: seen.append((it, cost))))
    assert (ra.iterations, ra.cost) == (rb.iterations, rb.cost) and seen[-1] == (rb.iterations, rb.cost)
    assert [it for it, _ in seen] == list(range(1, rb.iterations + 1))
    for ka, kb in zip(a, b):
        assert np.array_equal(ka.pose.matrix(), kb.pose.matrix()) and np.array_equal(ka.inverse_depth, kb.inverse_depth)


def test_the_memory_bounds_change_no_result(seq, keyframes):
    """Keyframes with compact images (as the window keeps those that leave it) and no room for the
    host factors' kept Jacobians: the same refined poses, depths and costs, bit for bit."""
    from factors.compact_image import compact_image  # noqa: PLC0415

    cam = seq.camera
    cfg = RefineConfig(max_iterations=3, max_scale_change=None)
    lean = [dataclasses.replace(k, image=compact_image(k.image), right=compact_image(k.right)) for k in keyframes]
    a = refine(cam.left, cam.baseline, keyframes, WindowConfig(), cfg)
    b = refine(cam.left, cam.baseline, lean, WindowConfig(), dataclasses.replace(cfg, jacobian_cache_mb=0))
    assert a.ran and b.ran and a.iterations == b.iterations
    assert (a.cost_before, a.cost_after) == (b.cost_before, b.cost_after)
    for ka, kb in zip(a.keyframes, b.keyframes):
        assert np.array_equal(ka.pose.matrix(), kb.pose.matrix()) and np.array_equal(ka.inverse_depth, kb.inverse_depth)


@pytest.mark.slow
def test_the_whole_log_graph_carries_the_wheel_odometry_and_both_solvers_agree(seq, keyframes):
    """With the run's wheel odometry the graph has its factors between consecutive keyframes and one
    calibration variable with its prior (the start cost grows by their error); GTSAM's LM and the
    hand-rolled one reach the same cost, poses and calibration; the window's owner is not changed."""
    from tests.test_window_wheel import _wheel  # noqa: PLC0415

    cam = seq.camera
    wheel = _wheel(seq)
    cfg = RefineConfig(max_iterations=30, relative_tolerance=1e-12, max_scale_change=None)
    out = {s: refine(cam.left, cam.baseline, keyframes, WindowConfig(), dataclasses.replace(cfg, solver=s),
                               photometric=NO_HUBER, wheel=wheel) for s in ("gtsam", "handrolled")}
    without = refine(cam.left, cam.baseline, keyframes, WindowConfig(), dataclasses.replace(cfg, max_iterations=1),
                               photometric=NO_HUBER)
    a, b = out["gtsam"], out["handrolled"]
    assert a.ran and b.ran and without.wheel_calibration is None
    assert a.cost_before == pytest.approx(b.cost_before, rel=1e-9) and a.cost_before - without.cost_before > 1.0
    assert a.cost_after == pytest.approx(b.cost_after, rel=1e-4)
    assert max(np.abs(x.pose.localCoordinates(y.pose)).max() for x, y in zip(a.keyframes, b.keyframes)) < 3e-5
    np.testing.assert_allclose(a.wheel_calibration, b.wheel_calibration, atol=1e-4)
    assert np.abs(a.wheel_calibration - 1.0).max() > 1e-3  # the wheels moved it
    np.testing.assert_array_equal(wheel.estimate, np.ones(3))


@pytest.mark.slow
def test_a_run_with_wheels_refines_the_calibration_of_the_log():
    """``gtvo run``'s refinement stage (:func:`gtvo.refinement.run.run_refinement`) hands the window's wheel
    calibration to the whole-log graph: the report's refine block has the refined calibration, near
    the wheels' truth (24 synthetic frames with simulated wheels). The stage returns a new result
    and leaves the one it was given as it was: the window's trajectory, depths and covariances."""
    from gtvo.config import WheelConfig, as_config  # noqa: PLC0415
    from gtvo.datasets.wheel import simulate_wheel_odometry  # noqa: PLC0415
    from gtvo.pipeline import run_odometry  # noqa: PLC0415
    from gtvo.refinement.run import run_refinement  # noqa: PLC0415
    from tests.test_odometry_wheel import BASE_TO_CAMERA, K_TRUE  # noqa: PLC0415

    seq = make_synthetic_sequence(24, width=240, height=180, step_m=0.1, motion="turn")
    log = simulate_wheel_odometry(seq.timestamps, np.asarray(seq.gt_poses),
                                  WheelConfig(base_to_camera=tuple(BASE_TO_CAMERA)).T_base_cam, "pose", K_TRUE,
                                  nominal_baseline=0.5)
    seq = dataclasses.replace(seq, wheel_odometry=log)
    cfg = as_config({"wheel": {"base_to_camera": BASE_TO_CAMERA}, "refine": {"enabled": True, "max_iterations": 2}})
    _, odo = run_odometry(seq, cfg, warn=lambda m: None)
    poses, depths = odo.trajectory.poses.copy(), {k: p.inverse_depth.copy() for k, p in odo.keyframe_points.items()}
    covariances = odo.covariances.covariance.copy()
    refined = run_refinement(odo, seq, warn=lambda m: None)
    assert refined is not odo and odo.refinement is None and refined.refinement["ran"]
    np.testing.assert_allclose(refined.refinement["wheel_calibration"], K_TRUE, atol=0.02)
    assert refined.covariances.source.startswith("gtsam.Marginals of the whole-log")
    assert not np.array_equal(refined.trajectory.poses, poses)  # the refined trajectory replaced the window's
    np.testing.assert_array_equal(odo.trajectory.poses, poses)  # ... in the new value only
    assert all(np.array_equal(odo.keyframe_points[k].inverse_depth, d) for k, d in depths.items())
    assert any(not np.array_equal(refined.keyframe_points[k].inverse_depth, d) for k, d in depths.items())
    np.testing.assert_array_equal(odo.covariances.covariance, covariances)


@pytest.mark.slow
def test_a_dropped_loop_edge_takes_its_photometric_loop_pairs_with_it(seq, keyframes):
    """With a window of 2 (a span of 1), a loop edge brings pairs across its ends; when the refined
    cost rejects it, the graph is solved again without those pairs too: as if it never was."""
    cam, window = seq.camera, WindowConfig(size=2)
    cfg = RefineConfig(max_iterations=10, max_scale_change=None)
    bad, kept = _edge(seq, 0, 8, dt=(0.4, 0.0, 0.0), sigma_t=0.1), _edge(seq, 4, 8)
    unscaled = dataclasses.replace(cfg, max_scale_change=None)
    loops = covisible_targets(cam.left, keyframes, window, unscaled, [(0, 4)])
    assert loops != covisible_targets(cam.left, keyframes, window, unscaled)  # the edge brings pairs
    without = refine(cam.left, cam.baseline, keyframes, window, cfg, loop_edges=[kept])
    res = refine(cam.left, cam.baseline, keyframes, window, cfg, loop_edges=[bad, kept])
    assert res.ran and res.loop_edges_dropped == 1 and res.loop_edges == 1
    assert res.targets_mean == without.targets_mean and res.cost_after == without.cost_after
    for ka, kb in zip(res.keyframes, without.keyframes):
        assert np.allclose(ka.pose.matrix(), kb.pose.matrix(), rtol=0, atol=1e-12)


@pytest.mark.slow
def test_a_run_with_an_imu_carries_its_factors_into_the_whole_log_graph():
    """With an IMU the whole-log graph has the window's IMU factors between consecutive keyframes
    with a state (their velocities, biases and gravity's tilt as variables, started at the window's
    estimates; docs/refinement.md): the report's refine block counts them, the refined trajectory
    is no worse than the window's (24 frames of the fast-turning synthetic log, 200 Hz IMU)."""
    from gtvo.config import as_config  # noqa: PLC0415
    from gtvo.datasets.synthetic_imu import ImuSimulation  # noqa: PLC0415
    from gtvo.evaluation.accuracy import evaluate, ground_truth  # noqa: PLC0415
    from gtvo.pipeline import run_odometry  # noqa: PLC0415
    from gtvo.refinement.run import run_refinement  # noqa: PLC0415

    seq = make_synthetic_sequence(24, width=240, height=180, motion="swerve", imu=ImuSimulation())
    _, odo = run_odometry(seq, as_config({"refine": {"enabled": True, "max_iterations": 3}}), warn=lambda m: None)
    assert odo.imu is not None and odo.imu.initialised
    refined = run_refinement(odo, seq, warn=lambda m: None)
    block = refined.refinement
    with_state = sum(1 for kf in odo.window_keyframes if kf.index in odo.imu.velocities)
    assert block["ran"] and with_state >= 5 and block["imu_factors"] == with_state - 1
    ate = [evaluate(*ground_truth(seq, t))["ate_rmse_m"] for t in (odo.trajectory, refined.trajectory)]
    assert ate[1] <= 1.1 * ate[0]
