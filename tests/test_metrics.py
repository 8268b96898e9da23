"""Metrics: hand-computed cases, the KITTI devkit's definition, and cross-checks against evo.

evo (GPL) is used here only, as an independent reference: its stored result files
(trajectory_eval_evo/res_files/*.zip) and its Python API on the same files.
"""

from __future__ import annotations

import io
import json
import zipfile
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from gtvo.errors import InputError
from gtvo.evaluation.metrics import (ErrorStatistics, align_trajectory, ate, drift_percent, kitti_segment_errors,
                          pairs_by_frames, pairs_by_path, rpe, umeyama_alignment)
from gtvo.evaluation.trajectory import Trajectory, synchronize
from gtvo.core.lie import invert_poses, make_poses
from gtvo.io.trajectory_files import read_kitti, read_trajectory

REL = 1e-6  # relative tolerance of every cross-check against evo


def random_walk(rng: np.random.Generator, n: int, step: float = 1.0) -> Trajectory:
    """A smooth random 3-D trajectory (positions and rotations both move)."""
    rotvec = np.cumsum(rng.normal(scale=0.05, size=(n, 3)), axis=0)
    p = np.cumsum(rng.normal(scale=step, size=(n, 3)), axis=0)
    return Trajectory(np.arange(n) * 0.1, make_poses(Rotation.from_rotvec(rotvec).as_matrix(), p))


def straight_line(n: int, step: float = 1.0, axis: int = 2) -> Trajectory:
    p = np.zeros((n, 3))
    p[:, axis] = np.arange(n) * step
    return Trajectory(np.arange(n) * 0.1, make_poses(np.tile(np.eye(3), (n, 1, 1)), p))


# ---- Umeyama ----------------------------------------------------------------------------------

def test_umeyama_recovers_random_sim3_and_se3():
    rng = np.random.default_rng(10)
    for trial in range(20):
        X = rng.normal(size=(50, 3)) * 3.0
        R = Rotation.random(random_state=trial).as_matrix()
        t = rng.normal(size=3) * 10
        s = float(rng.uniform(0.2, 5.0))
        S = umeyama_alignment(X, s * X @ R.T + t, with_scale=True)
        np.testing.assert_allclose(S.rotation, R, atol=1e-10)
        np.testing.assert_allclose(S.translation, t, atol=1e-9)
        assert S.scale == pytest.approx(s, rel=1e-10)
        E = umeyama_alignment(X, X @ R.T + t, with_scale=False)
        np.testing.assert_allclose(E.rotation, R, atol=1e-10)
        np.testing.assert_allclose(E.translation, t, atol=1e-9)
        assert E.scale == 1.0
        np.testing.assert_allclose(S.matrix()[:3, :3], s * R, atol=1e-9)


def test_umeyama_matches_evo_with_noise():
    geometry = pytest.importorskip("evo.core.geometry")
    rng = np.random.default_rng(11)
    X = rng.normal(size=(40, 3))
    Y = 1.7 * X @ Rotation.random(random_state=1).as_matrix().T + 3.0 + rng.normal(scale=0.05, size=X.shape)
    for with_scale in (False, True):
        ours = umeyama_alignment(X, Y, with_scale)
        r, t, c = geometry.umeyama_alignment(X.T, Y.T, with_scale)
        np.testing.assert_allclose(ours.rotation, r, atol=1e-12)
        np.testing.assert_allclose(ours.translation, t, atol=1e-12)
        assert ours.scale == pytest.approx(c, rel=1e-12)


def test_umeyama_rejects_degenerate_input():
    line = np.outer(np.arange(10.0), [1.0, 2.0, 3.0])
    with pytest.raises(InputError, match="degenerate"):
        umeyama_alignment(line, line + 1.0)
    with pytest.raises(InputError, match="at least 3"):
        umeyama_alignment(np.zeros((2, 3)), np.zeros((2, 3)))
    with pytest.raises(InputError, match="same shape"):
        umeyama_alignment(np.zeros((5, 3)), np.zeros((4, 3)))
    bad = np.random.default_rng(0).normal(size=(5, 3))
    bad[2, 1] = np.nan
    with pytest.raises(InputError, match="NaN"):
        umeyama_alignment(bad, bad)


# ---- ATE ---------------------------------------------------------------------------------------

def test_ate_zero_after_se3_alignment_of_rigid_copy():
    rng = np.random.default_rng(12)
    ref = random_walk(rng, 100)
    G = make_poses(Rotation.random(random_state=3).as_matrix()[None], [[4.0, -2.0, 7.0]])[0]
    est = ref.transform(G)
    res = ate(est, ref, "se3")
    assert res.rmse < 1e-12
    assert res.rotation_deg.max < 1e-9
    assert ate(est, ref, "none").rmse > 1.0  # not zero without alignment
    # A scaled copy needs Sim(3).
    scaled = ref.transform(G, scale=0.3)
    assert ate(scaled, ref, "sim3").rmse < 1e-12
    assert ate(scaled, ref, "sim3").alignment.scale == pytest.approx(1 / 0.3, rel=1e-12)
    assert ate(scaled, ref, "se3").rmse > 0.1


def test_ate_known_offset_and_rotation():
    ref = straight_line(30)
    offset = np.array([0.3, -0.4, 0.0])  # |offset| = 0.5 m
    yaw = np.radians(2.0)
    Rz = Rotation.from_rotvec([0, 0, yaw]).as_matrix()
    est = Trajectory(ref.timestamps, make_poses(ref.rotations @ Rz, ref.positions + offset))
    res = ate(est, ref, "none")
    np.testing.assert_allclose(res.translation_errors, 0.5, rtol=1e-14)
    np.testing.assert_allclose(res.rotation_errors_deg, 2.0, rtol=1e-9)
    assert res.translation.rmse == pytest.approx(0.5) and res.translation.std == pytest.approx(0.0, abs=1e-15)
    # "origin" maps est_0 = (Rz, offset) onto ref_0 = I: est_i -> (Rz^T R_i Rz, Rz^T p_i) = (I, p_i)
    # because the line runs along z, the yaw axis. So every error vanishes.
    origin = ate(est, ref, "origin")
    assert origin.rmse < 1e-12 and origin.rotation_deg.max < 1e-9
    # SE(3) alignment removes a pure offset entirely (a curved path: a line is degenerate).
    curve = random_walk(np.random.default_rng(16), 30)
    shifted = Trajectory(curve.timestamps, make_poses(curve.rotations, curve.positions + offset))
    assert ate(shifted, curve, "se3").rmse < 1e-12
    with pytest.raises(InputError, match="degenerate"):
        ate(est, ref, "se3")


def test_error_statistics_definitions():
    s = ErrorStatistics.of([3.0, 4.0])
    assert s.rmse == pytest.approx(np.sqrt(12.5))
    assert (s.mean, s.median, s.min, s.max, s.sse, s.count) == (3.5, 3.5, 3.0, 4.0, 25.0, 2)
    assert s.std == pytest.approx(0.5)  # population std
    with pytest.raises(InputError):
        ErrorStatistics.of([])


def test_metrics_reject_unassociated_and_bad_options():
    a, b = straight_line(10), straight_line(11)
    for fn in (lambda: ate(a, b), lambda: rpe(a, b), lambda: drift_percent(a, b), lambda: kitti_segment_errors(a, b)):
        with pytest.raises(InputError, match="associate"):
            fn()
    with pytest.raises(InputError, match="alignment"):
        ate(a, a, "affine")  # type: ignore[arg-type]
    with pytest.raises(InputError, match="no pose pair"):
        rpe(a, a, delta=50, delta_unit="frames")
    with pytest.raises(InputError, match="integer"):
        rpe(a, a, delta=1.5, delta_unit="frames")
    with pytest.raises(InputError, match="unit"):
        rpe(a, a, delta=1, delta_unit="s")  # type: ignore[arg-type]
    with pytest.raises(InputError):
        kitti_segment_errors(a, a, lengths=(0.0,))
    with pytest.raises(InputError):
        drift_percent(Trajectory(np.arange(3.0), np.tile(np.eye(4), (3, 1, 1))),
                      Trajectory(np.arange(3.0), np.tile(np.eye(4), (3, 1, 1))))


# ---- RPE ---------------------------------------------------------------------------------------

def test_pairs_hand_cases():
    np.testing.assert_array_equal(pairs_by_frames(7, 3), [[0, 3], [3, 6]])
    np.testing.assert_array_equal(pairs_by_frames(7, 1)[:, 0], np.arange(6))
    # 1 m steps, delta 2.5 m: the path reaches >= 2.5 m after 3 steps.
    P = straight_line(10).positions
    np.testing.assert_array_equal(pairs_by_path(P, 2.5), [[0, 3], [3, 6], [6, 9]])
    np.testing.assert_array_equal(pairs_by_path(P, 2.5, legacy=True), [[3, 6], [6, 9]])
    # Uneven steps: 0.5, 0.5, 3, 0.1, 0.1, 1.0 -> cumulative 0.5 1 4 | 0.1 0.2 1.2
    steps = np.array([0.5, 0.5, 3.0, 0.1, 0.1, 1.0])
    P = np.zeros((7, 3))
    P[1:, 0] = np.cumsum(steps)
    np.testing.assert_array_equal(pairs_by_path(P, 1.0), [[0, 2], [2, 3], [3, 6]])
    assert pairs_by_path(P, 100.0).shape == (0, 2)


def test_rpe_hand_scale_drift_and_rotation_drift():
    ref = straight_line(21)  # 1 m steps along z, no rotation
    scaled = Trajectory(ref.timestamps, make_poses(ref.rotations, 1.1 * ref.positions))
    res = rpe(scaled, ref, delta=1)
    np.testing.assert_allclose(res.translation_errors, 0.1, rtol=1e-12)
    np.testing.assert_allclose(res.rotation_errors_deg, 0.0, atol=1e-12)
    assert res.translation.count == 20
    res5 = rpe(scaled, ref, delta=5)  # pairs (0,5),(5,10),... each 5 m: error 0.5 m
    np.testing.assert_allclose(res5.translation_errors, 0.5, rtol=1e-12)
    # A yaw error of 1 degree added at every step: the relative rotation over one step is off by 1 deg.
    yaw = np.radians(np.arange(21) * 1.0)
    R = Rotation.from_rotvec(np.column_stack([np.zeros(21), np.zeros(21), yaw])).as_matrix()
    turning = Trajectory(ref.timestamps, make_poses(R, ref.positions))
    res = rpe(turning, ref, delta=1)
    np.testing.assert_allclose(res.rotation_errors_deg, 1.0, rtol=1e-9)
    # Relative errors do not depend on the world frame of the estimate.
    G = make_poses(Rotation.random(random_state=5).as_matrix()[None], [[1.0, 2.0, 3.0]])[0]
    moved = rpe(turning.transform(G), ref, delta=1)
    np.testing.assert_allclose(moved.translation_errors, res.translation_errors, atol=1e-12)


def test_rpe_metres_pairs_from_est_or_ref():
    ref = straight_line(41)
    est = Trajectory(ref.timestamps, make_poses(ref.rotations, 2.0 * ref.positions))
    # est moves 2 m a step, so 4 m of its path is 2 steps; ref needs 4 steps.
    np.testing.assert_array_equal(rpe(est, ref, 4.0, "m").pairs[:2], [[0, 2], [2, 4]])
    np.testing.assert_array_equal(rpe(est, ref, 4.0, "m", pairs_from="ref").pairs[:2], [[0, 4], [4, 8]])


# ---- drift and KITTI segments -------------------------------------------------------------------

def test_drift_percent_hand_case():
    ref = straight_line(101)  # 100 m along z
    est_p = ref.positions.copy()
    est_p[-1] += [2.0, 0.0, 0.0]  # ends 2 m to the side
    G = make_poses(Rotation.random(random_state=7).as_matrix()[None], [[5.0, 5.0, 5.0]])[0]
    est = Trajectory(ref.timestamps, make_poses(ref.rotations, est_p)).transform(G)  # other world frame
    assert drift_percent(est, ref) == pytest.approx(2.0, rel=1e-12)


def devkit_segment_errors(est: Trajectory, ref: Trajectory, lengths, step):
    """A literal loop transcription of the devkit's calcSequenceErrors (the test's reference)."""
    P_gt, P_res = ref.poses, est.poses
    dist = [0.0]
    for i in range(1, len(P_gt)):
        dist.append(dist[i - 1] + float(np.linalg.norm(P_gt[i, :3, 3] - P_gt[i - 1, :3, 3])))
    dist = np.array(dist)
    out = []
    for first in range(0, len(P_gt), step):
        for length in lengths:
            after = np.nonzero(dist[first:] > dist[first] + length)[0]
            if after.size == 0:
                continue
            last = first + int(after[0])
            d_gt = np.linalg.inv(P_gt[first]) @ P_gt[last]
            d_res = np.linalg.inv(P_res[first]) @ P_res[last]
            E = np.linalg.inv(d_res) @ d_gt
            r = np.arccos(max(min(0.5 * (np.trace(E[:3, :3]) - 1.0), 1.0), -1.0))
            out.append((first, last, length, np.linalg.norm(E[:3, 3]) / length, r / length))
    return out


def test_kitti_segments_hand_scale_drift():
    ref = straight_line(300)  # 1 m steps: dist[l] > dist[f] + 100 first at l = f + 101
    est = Trajectory(ref.timestamps, make_poses(ref.rotations, 1.01 * ref.positions))
    res = kitti_segment_errors(est, ref, lengths=(100.0,), step=10)
    np.testing.assert_array_equal(res.last_frames - res.first_frames, 101)
    # |E_t| = 1.01 * 101 - 101 = 1.01 m over a nominal 100 m: 1.01 %.
    assert res.translation_percent == pytest.approx(1.01, rel=1e-9)
    assert res.rotation_deg_per_100m == pytest.approx(0.0, abs=1e-9)
    assert len(res.first_frames) == len(range(0, 300 - 101, 10))
    assert kitti_segment_errors(est, ref) is not None  # 100 m fits in 299 m
    assert kitti_segment_errors(est, straight_line(300)) is not None


def test_kitti_segments_none_when_too_short_and_custom_lengths():
    ref = straight_line(50, step=0.5)  # 24.5 m
    est = Trajectory(ref.timestamps, make_poses(ref.rotations, 1.02 * ref.positions))
    assert kitti_segment_errors(est, ref) is None
    res = kitti_segment_errors(est, ref, lengths=(5.0, 10.0), step=1)
    assert set(res.per_length) == {5.0, 10.0}
    assert res.translation_percent > 2.0  # nominal length < travelled length inflates the ratio


def test_kitti_segments_match_devkit_transcription():
    rng = np.random.default_rng(13)
    ref = random_walk(rng, 400, step=0.7)
    est = random_walk(np.random.default_rng(14), 400, step=0.05)
    est = Trajectory(ref.timestamps, ref.poses @ est.relative_to_first().poses)  # ref plus a wandering error
    lengths = (20.0, 50.0, 100.0, 200.0)
    res = kitti_segment_errors(est, ref, lengths=lengths, step=7)
    want = devkit_segment_errors(est, ref, lengths, 7)
    assert len(want) == len(res.first_frames)
    got = sorted(zip(res.first_frames.tolist(), res.last_frames.tolist(), res.segment_lengths.tolist(),
                     res.translation_ratios.tolist(), res.rotation_rad_per_m.tolist()))
    for g, w in zip(got, sorted(want)):
        assert g[:3] == w[:3]
        assert g[3] == pytest.approx(w[3], rel=1e-9, abs=1e-14)
        assert g[4] == pytest.approx(w[4], rel=1e-6, abs=1e-9)  # acos of a trace: fewer digits
    assert res.translation_percent == pytest.approx(100 * np.mean([w[3] for w in want]), rel=1e-9)


# ---- real data: evo's stored results and evo's API ---------------------------------------------

@pytest.fixture(scope="module")
def evo_dir(shared_data: Path) -> Path:
    d = shared_data / "trajectory_eval_evo"
    if not d.is_dir():
        pytest.skip(f"{d} not found")
    return d


@pytest.fixture(scope="module")
def kitti00(evo_dir: Path):
    ref = read_kitti(evo_dir / "KITTI_00_gt.txt", evo_dir / "KITTI_00_gt_times.txt")
    ests = {name: read_kitti(evo_dir / f"KITTI_00_{name}.txt", evo_dir / "KITTI_00_gt_times.txt")
            for name in ("ORB", "SPTAM")}
    return ref, ests


def load_evo_result(zip_path: Path) -> tuple[dict, np.ndarray]:
    with zipfile.ZipFile(zip_path) as z:
        stats = json.loads(z.read("stats.json"))
        errors = np.load(io.BytesIO(z.read("error_array.npz")))
    return stats, np.asarray(errors)


def assert_stats_match(ours: ErrorStatistics, stats: dict) -> None:
    for key in ("rmse", "mean", "median", "std", "min", "max", "sse"):
        assert getattr(ours, key) == pytest.approx(stats[key], rel=REL), key


@pytest.mark.realdata
@pytest.mark.parametrize("name", ["ORB", "SPTAM"])
def test_kitti00_matches_evo_stored_results(kitti00, evo_dir, name):
    ref, ests = kitti00
    est = ests[name]
    stats, errors = load_evo_result(evo_dir / "res_files" / f"{name.lower()}_ape.zip")
    res = ate(est, ref, "se3")
    assert_stats_match(res.translation, stats)
    np.testing.assert_allclose(res.translation_errors, errors, rtol=REL)
    # The stored RPE (delta 10 m, consecutive pairs from the estimate's path) was made by an older
    # evo release that started the pairs only after the first delta.
    stats, errors = load_evo_result(evo_dir / "res_files" / f"{name.lower()}_rpe.zip")
    res = rpe(est, ref, delta=10.0, delta_unit="m", legacy_path_pairs=True)
    assert_stats_match(res.translation, stats)
    np.testing.assert_allclose(res.translation_errors, errors, rtol=REL)


@pytest.mark.realdata
def test_kitti00_orb_segment_metric_published(kitti00):
    # ORB-SLAM2's paper (Mur-Artal & Tardos 2017, table 2) reports 0.70 % and 0.25 deg/100 m on KITTI 00.
    ref, ests = kitti00
    res = kitti_segment_errors(ests["ORB"], ref)
    assert round(res.translation_percent, 2) == 0.70
    assert round(res.rotation_deg_per_100m, 2) == 0.25


def evo_traj(path: Path):
    file_interface = pytest.importorskip("evo.tools.file_interface")
    if path.suffix == ".csv":
        return file_interface.read_euroc_csv_trajectory(str(path))
    return file_interface.read_tum_trajectory_file(str(path))


# (reference, estimate, alignment, ATE rmse in the folder's README)
EVO_CASES = [
    ("freiburg1_xyz-groundtruth.txt", "freiburg1_xyz-rgbdslam.txt", "se3", 0.013470),
    ("fr2_desk_groundtruth.txt", "fr2_desk_ORB.txt", "se3", 0.008119),
    ("V102_groundtruth.csv", "V102.txt", "se3", 0.091727),
    ("freiburg1_xyz-groundtruth.txt", "freiburg1_xyz-ORB_kf_mono.txt", "sim3", 0.009755),
    ("fr2_desk_groundtruth.txt", "fr2_desk_ORB_kf_mono.txt", "sim3", 0.007729),
    ("V101_gt.txt", "V101_openvins.txt", "se3", 0.052102),
]


@pytest.mark.slow
@pytest.mark.realdata
@pytest.mark.parametrize("ref_name, est_name, align, readme_rmse", EVO_CASES)
def test_ate_rpe_match_evo_api(evo_dir, ref_name, est_name, align, readme_rmse):
    evo_sync = pytest.importorskip("evo.core.sync")
    evo_metrics = pytest.importorskip("evo.core.metrics")
    from evo.core.units import Unit

    # evo: associate, align (Umeyama, with scale for Sim(3)), APE translation part.
    e_ref, e_est = evo_sync.associate_trajectories(evo_traj(evo_dir / ref_name), evo_traj(evo_dir / est_name))
    e_est.align(e_ref, correct_scale=(align == "sim3"))
    ape = evo_metrics.APE(evo_metrics.PoseRelation.translation_part)
    ape.process_data((e_ref, e_est))
    ape_rot = evo_metrics.APE(evo_metrics.PoseRelation.rotation_angle_deg)
    ape_rot.process_data((e_ref, e_est))

    ref, est = synchronize(read_trajectory(evo_dir / ref_name), read_trajectory(evo_dir / est_name))
    np.testing.assert_allclose(ref.timestamps, e_ref.timestamps, rtol=0, atol=0)
    np.testing.assert_allclose(est.timestamps, e_est.timestamps, rtol=0, atol=0)
    res = ate(est, ref, align)
    assert res.rmse == pytest.approx(ape.get_statistic(evo_metrics.StatisticsType.rmse), rel=REL)
    assert round(res.rmse, 6) == pytest.approx(readme_rmse, abs=1.01e-6)
    np.testing.assert_allclose(res.translation_errors, ape.error, rtol=REL, atol=1e-12)
    np.testing.assert_allclose(res.rotation_errors_deg, ape_rot.error, rtol=REL, atol=1e-9)

    # RPE on the aligned (for Sim(3): scaled) estimate, as evo_rpe -a / -as does.
    aligned, _ = align_trajectory(est, ref, align)
    cases = [(1, Unit.frames, "frames", False), (0.5, Unit.meters, "m", False), (0.5, Unit.meters, "m", True)]
    for delta, unit, our_unit, from_ref in cases:
        ours = rpe(aligned, ref, delta=delta, delta_unit=our_unit, pairs_from="ref" if from_ref else "est")
        for relation, errors in ((evo_metrics.PoseRelation.translation_part, ours.translation_errors),
                                 (evo_metrics.PoseRelation.rotation_angle_deg, ours.rotation_errors_deg)):
            m = evo_metrics.RPE(relation, delta, unit, pairs_from_reference=from_ref)
            m.process_data((e_ref, e_est))
            np.testing.assert_array_equal(ours.pairs[:, 1], m.delta_ids)
            np.testing.assert_allclose(errors, m.error, rtol=REL, atol=1e-9)


@pytest.mark.realdata
def test_kitti00_rpe_metres_matches_current_evo(kitti00):
    evo_metrics = pytest.importorskip("evo.core.metrics")
    file_interface = pytest.importorskip("evo.tools.file_interface")
    from evo.core.units import Unit

    ref, ests = kitti00
    e_ref = file_interface.read_kitti_poses_file(ref.name)
    e_est = file_interface.read_kitti_poses_file(ests["SPTAM"].name)
    m = evo_metrics.RPE(evo_metrics.PoseRelation.translation_part, 10.0, Unit.meters)
    m.process_data((e_ref, e_est))
    res = rpe(ests["SPTAM"], ref, 10.0, "m")
    np.testing.assert_array_equal(res.pairs[:, 1], m.delta_ids)
    np.testing.assert_allclose(res.translation_errors, m.error, rtol=REL)


def test_invert_helper_used_by_rpe_is_transpose_inverse():
    # RPE/KITTI use [R^T, -R^T t] like evo and the devkit (exact for rotations).
    rng = np.random.default_rng(15)
    T = random_walk(rng, 5).poses
    np.testing.assert_allclose(invert_poses(T), np.linalg.inv(T), atol=1e-12)
