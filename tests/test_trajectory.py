"""Trajectory type, SE(3)/quaternion helpers and timestamp association (evo cross-checked)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from gtvo.errors import InputError
from gtvo.evaluation.trajectory import Trajectory, associate, matching_time_indices, synchronize
from gtvo.core.lie import invert_poses, make_poses, quaternions_to_rotations, rotation_angle, rotations_to_quaternions


def random_poses(rng: np.random.Generator, n: int) -> np.ndarray:
    R = Rotation.random(n, random_state=int(rng.integers(1 << 31))).as_matrix()
    return make_poses(R, rng.normal(size=(n, 3)) * 5.0)


def test_positions_and_path_length_square():
    # A unit square walked once: 4 sides of 1 m.
    p = np.array([[0, 0, 0], [1, 0, 0], [1, 0, 1], [0, 0, 1], [0, 0, 0]], float)
    traj = Trajectory(np.arange(5.0), make_poses(np.tile(np.eye(3), (5, 1, 1)), p))
    np.testing.assert_array_equal(traj.positions, p)
    assert traj.path_length() == pytest.approx(4.0, abs=1e-15)
    np.testing.assert_allclose(traj.distances(), [0, 1, 2, 3, 4], atol=1e-15)
    assert traj.duration() == 4.0
    assert len(traj) == 5


def test_relative_to_first_keeps_relative_motion():
    rng = np.random.default_rng(1)
    T = random_poses(rng, 20)
    traj = Trajectory(np.arange(20.0), T)
    rel = traj.relative_to_first()
    np.testing.assert_allclose(rel.poses[0], np.eye(4), atol=1e-12)
    # T_i^-1 T_j is unchanged by a change of world frame.
    a = invert_poses(T[3]) @ T[11]
    b = invert_poses(rel.poses[3]) @ rel.poses[11]
    np.testing.assert_allclose(a, b, atol=1e-12)
    # And it is T_0^-1 T_i exactly.
    np.testing.assert_allclose(rel.poses, invert_poses(T[0])[None] @ T, atol=1e-12)


def test_transform_with_scale_is_sim3_on_positions_only():
    rng = np.random.default_rng(2)
    traj = Trajectory(np.arange(10.0), random_poses(rng, 10))
    G = random_poses(rng, 1)[0]
    out = traj.transform(G, scale=2.5)
    np.testing.assert_allclose(out.positions, 2.5 * traj.positions @ G[:3, :3].T + G[:3, 3], atol=1e-12)
    np.testing.assert_allclose(out.rotations, G[:3, :3] @ traj.rotations, atol=1e-12)
    np.testing.assert_allclose(traj.transform(G).poses, G[None] @ traj.poses, atol=1e-12)
    with pytest.raises(InputError):
        traj.transform(np.eye(3))
    with pytest.raises(InputError):
        traj.transform(G, scale=0.0)


def test_invert_poses():
    rng = np.random.default_rng(3)
    T = random_poses(rng, 7)
    np.testing.assert_allclose(invert_poses(T) @ T, np.tile(np.eye(4), (7, 1, 1)), atol=1e-12)


def test_quaternion_roundtrip_and_sign():
    rng = np.random.default_rng(4)
    rot = Rotation.random(200, random_state=4)
    q = rot.as_quat()  # scipy: x, y, z, w (TUM order)
    np.testing.assert_allclose(quaternions_to_rotations(q), rot.as_matrix(), atol=1e-14)
    np.testing.assert_allclose(quaternions_to_rotations(-q), rot.as_matrix(), atol=1e-14)  # q ~ -q
    np.testing.assert_allclose(quaternions_to_rotations(3.0 * q), rot.as_matrix(), atol=1e-14)  # normalised
    back = rotations_to_quaternions(rot.as_matrix())
    assert np.all(back[:, 3] >= 0)
    np.testing.assert_allclose(np.abs(np.sum(back * q, axis=1)), 1.0, atol=1e-14)
    # Angles near pi (every Shepperd branch) and exactly pi about each axis.
    axes = rng.normal(size=(50, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    near_pi = Rotation.from_rotvec(axes * (np.pi - rng.uniform(0, 1e-6, size=(50, 1)))).as_matrix()
    exact_pi = Rotation.from_rotvec(np.pi * np.eye(3)).as_matrix()
    for R in (near_pi, exact_pi, np.eye(3)[None]):
        np.testing.assert_allclose(quaternions_to_rotations(rotations_to_quaternions(R)), R, atol=1e-13)


def test_rotation_angle_small_and_large():
    angles = np.array([0.0, 1e-9, 1e-5, 0.3, 2.0, np.pi - 1e-7])
    rng = np.random.default_rng(5)
    axes = rng.normal(size=(len(angles), 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    R = Rotation.from_rotvec(axes * angles[:, None]).as_matrix()
    np.testing.assert_allclose(rotation_angle(R), angles, rtol=1e-7, atol=1e-15)


@pytest.mark.parametrize("bad, message", [
    (dict(timestamps=np.array([0.0, 1.0, 0.5])), "backwards at pose 2"),
    (dict(timestamps=np.array([0.0, np.nan, 2.0])), "NaN"),
    (dict(timestamps=np.zeros(0), poses=np.zeros((0, 4, 4))), "empty"),
    (dict(poses=np.zeros((3, 3, 4))), "shape"),
])
def test_trajectory_rejects_bad_input(bad, message):
    args = dict(timestamps=np.arange(3.0), poses=np.tile(np.eye(4), (3, 1, 1)))
    args.update(bad)
    with pytest.raises(InputError, match=message):
        Trajectory(args["timestamps"], args["poses"], name="mytraj")


def test_trajectory_rejects_nan_pose_and_bad_last_row():
    T = np.tile(np.eye(4), (3, 1, 1))
    T[1, 0, 3] = np.nan
    with pytest.raises(InputError, match="pose 1"):
        Trajectory(np.arange(3.0), T)
    T = np.tile(np.eye(4), (3, 1, 1))
    T[2, 3, 0] = 1.0
    with pytest.raises(InputError, match="last row"):
        Trajectory(np.arange(3.0), T)


def test_duplicate_timestamps_allowed():
    Trajectory(np.array([0.0, 1.0, 1.0, 2.0]), np.tile(np.eye(4), (4, 1, 1)))


# ---- association ----------------------------------------------------------------------------

def test_matching_hand_case():
    s1 = np.array([0.0, 1.0, 2.004, 3.5, 5.0])
    s2 = np.array([0.001, 0.5, 1.0, 2.0, 2.01, 4.9])
    i1, i2 = matching_time_indices(s1, s2, max_diff=0.01)
    # 0.0->0.001, 1.0->1.0, 2.004->2.0 (closer than 2.01), 3.5 none, 5.0 none (0.1 away)
    np.testing.assert_array_equal(i1, [0, 1, 2])
    np.testing.assert_array_equal(i2, [0, 2, 3])
    # An offset moves stamps_2: s2 + 0.1 puts 4.9 onto 5.0.
    i1, i2 = matching_time_indices(s1, s2, max_diff=0.01, offset_2=0.1)
    assert (4, 5) in set(zip(i1.tolist(), i2.tolist()))


def test_matching_tie_and_duplicates():
    # Exactly halfway: the earlier stamp wins; among duplicates the last one is taken.
    i1, i2 = matching_time_indices(np.array([1.5]), np.array([1.0, 2.0]), max_diff=1.0)
    np.testing.assert_array_equal(i2, [0])
    i1, i2 = matching_time_indices(np.array([1.0]), np.array([0.0, 1.0, 1.0, 3.0]), max_diff=0.1)
    np.testing.assert_array_equal(i2, [2])


def test_matching_rejects_bad_input():
    with pytest.raises(InputError):
        matching_time_indices([0.0], [1.0, 0.0])
    with pytest.raises(InputError):
        matching_time_indices([0.0], [0.0], max_diff=-1.0)


def test_associate_against_evo_random():
    sync = pytest.importorskip("evo.core.sync")
    rng = np.random.default_rng(6)
    for trial in range(30):
        n1, n2 = int(rng.integers(1, 60)), int(rng.integers(1, 60))
        s1 = np.sort(rng.uniform(0, 1, n1)).round(3)  # rounding creates duplicates and exact ties
        s2 = np.sort(rng.uniform(-0.05, 1.05, n2)).round(3)
        max_diff = float(rng.choice([0.0, 0.001, 0.01, 0.05]))
        offset = float(rng.choice([0.0, 0.002, -0.01]))
        ours = matching_time_indices(s1, s2, max_diff, offset)
        theirs = sync.matching_time_indices(s1, s2.copy(), max_diff, offset)
        np.testing.assert_array_equal(ours[0], theirs[0], err_msg=f"trial {trial}")
        np.testing.assert_array_equal(ours[1], theirs[1], err_msg=f"trial {trial}")


def test_associate_starts_from_shorter_and_raises_when_none():
    ref = Trajectory(np.arange(0.0, 10.0, 0.1), np.tile(np.eye(4), (100, 1, 1)), name="ref")
    est = Trajectory(np.array([0.2, 0.503, 5.0]), np.tile(np.eye(4), (3, 1, 1)), name="est")
    i_ref, i_est = associate(ref, est)
    np.testing.assert_array_equal(i_est, [0, 1, 2])
    np.testing.assert_array_equal(i_ref, [2, 5, 50])
    r, e = synchronize(ref, est)
    assert len(r) == len(e) == 3
    far = Trajectory(np.array([100.0]), np.eye(4)[None], name="far")
    with pytest.raises(InputError, match="no matching timestamps"):
        associate(ref, far)


def test_pose_from_xyz_quaternion_is_the_translation_and_the_rotation_of_its_quaternion():
    from gtvo.core.lie import pose_from_xyz_quaternion

    q = np.array([-0.5, 0.5, -0.5, 0.5])  # a forward camera on a REP 103 base: camera z -> base x
    T = pose_from_xyz_quaternion([0.3, -0.1, 0.8, *q])
    np.testing.assert_allclose(T[:3, 3], [0.3, -0.1, 0.8])
    np.testing.assert_allclose(T[:3, :3], quaternions_to_rotations(q)[0])
    np.testing.assert_allclose(T[:3, :3] @ [0.0, 0.0, 1.0], [1.0, 0.0, 0.0], atol=1e-15)
    np.testing.assert_array_equal(T[3], [0.0, 0.0, 0.0, 1.0])
