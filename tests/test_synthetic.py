"""The synthetic stereo sequence: determinism, exact geometry, photometric consistency, I/O."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

import gtvo.datasets.synthetic_scene as synthetic_scene
from gtvo.core.atomic import DIR_MARKER
from gtvo.core.camera import PinholeCamera
from gtvo.errors import InputError
from gtvo.core.image import bilinear_sample
from gtvo.datasets.sequence import Sequence
from gtvo.datasets.synthetic_scene import SyntheticScene
from gtvo.datasets.synthetic import (SyntheticSequence, make_synthetic_sequence, synthetic_trajectory,
                            write_sequence_kitti)


@pytest.fixture(scope="module")
def seq() -> SyntheticSequence:
    return make_synthetic_sequence(n_frames=12)


def pixel_grid(cam: PinholeCamera) -> np.ndarray:
    v, u = np.mgrid[0:cam.height, 0:cam.width]
    return np.stack([u.ravel(), v.ravel()], axis=1).astype(float)


def warp_consistency(seq: SyntheticSequence, i: int, j: int) -> tuple[np.ndarray, int]:
    """|I_i(p) - I_j(p')| over interior, unoccluded pixels p of frame i, p' from exact depth and GT poses."""
    cam = seq.pinhole
    uv = pixel_grid(cam)
    X_i = cam.backproject(uv, seq.true_depth(i).ravel())
    T_j_i = np.linalg.inv(seq.gt_poses[j]) @ seq.gt_poses[i]
    X_j = X_i @ T_j_i[:3, :3].T + T_j_i[:3, 3]
    uv_j, in_front = cam.project(X_j)
    I_j, ok = bilinear_sample(seq.left(j), uv_j[:, 0], uv_j[:, 1], border=1)
    z_j, _ = bilinear_sample(seq.true_depth(j), uv_j[:, 0], uv_j[:, 1], border=1)
    # Not occluded: the target's own depth there agrees with the warped point's z.
    visible = in_front & ok & (np.abs(z_j - X_j[:, 2]) < 0.01 * X_j[:, 2])
    # Interior in both frames: no crease or silhouette near the pixel or near its target.
    interior_j, _ = bilinear_sample(seq.interior_mask(j).astype(np.float32), uv_j[:, 0], uv_j[:, 1])
    keep = visible & seq.interior_mask(i).ravel() & (interior_j == 1.0)
    return np.abs(seq.left(i).ravel() - I_j)[keep], int(keep.sum())


# ------------------------------------------------------------------------------------ determinism


@pytest.mark.slow
def test_same_seed_gives_byte_identical_images():
    a = make_synthetic_sequence(n_frames=4, seed=3, noise_sigma=2.0, exposure_change=True)
    synthetic_scene._cached_scene.cache_clear()  # rebuild the textures too, not only reuse the cached scene
    b = make_synthetic_sequence(n_frames=4, seed=3, noise_sigma=2.0, exposure_change=True)
    assert a.scene is not b.scene
    for i in (3, 0):  # rendering order does not matter either
        assert a.left(i).tobytes() == b.left(i).tobytes()
        assert a.right(i).tobytes() == b.right(i).tobytes()
        assert a.true_depth(i).tobytes() == b.true_depth(i).tobytes()
    np.testing.assert_array_equal(a.gt_poses, b.gt_poses)
    c = make_synthetic_sequence(n_frames=4, seed=4)
    assert np.mean(np.abs(c.left(0) - a.left(0))) > 5.0


@pytest.mark.slow
def test_cached_images_are_copies(seq):
    img = seq.left(1)
    img[:] = 0
    assert seq.left(1).max() > 0


# -------------------------------------------------------------------------------- sequence checks


def test_sequence_type_and_validation(seq):
    assert isinstance(seq, Sequence) and seq.kind == "stereo" and len(seq) == 12
    np.testing.assert_allclose(np.diff(seq.timestamps), 0.1)
    assert seq.timestamps[0] == 0.0 and seq.has_ground_truth
    cam = seq.camera
    assert cam.left.fx == pytest.approx(0.9 * 320) and cam.baseline == pytest.approx(0.5)
    assert (cam.left.cx, cam.left.cy) == (159.5, 119.5)
    f = seq.frame(5)
    assert f.left.shape == f.right.shape == (240, 320) and f.left.dtype == np.float32
    assert f.depth is None and f.gt_T_world_cam is not None
    with pytest.raises(IndexError):
        seq.frame(12)
    short = seq.truncated(3)
    assert isinstance(short, SyntheticSequence) and len(short) == 3
    assert short.left(2).tobytes() == seq.left(2).tobytes()
    np.testing.assert_array_equal(short.true_depth(2), seq.true_depth(2))


def test_poses_are_rigid_and_the_motion_is_moderate(seq):
    T = seq.gt_poses
    np.testing.assert_allclose(T[0], np.eye(4), atol=1e-15)
    R = T[:, :3, :3]
    np.testing.assert_allclose(R @ R.transpose(0, 2, 1), np.broadcast_to(np.eye(3), R.shape), atol=1e-12)
    np.testing.assert_allclose(np.linalg.det(R), 1.0, atol=1e-12)
    rel = np.linalg.inv(T[:-1]) @ T[1:]
    steps = np.linalg.norm(rel[:, :3, 3], axis=1)
    assert np.all((steps > 0.1) & (steps < 0.2))
    angles = np.degrees(np.arccos(np.clip((np.trace(rel[:, :3, :3], axis1=1, axis2=2) - 1) / 2, -1, 1)))
    assert np.all(angles < 1.0) and angles.max() > 0.1  # rotates, a few degrees per second at most


@pytest.mark.slow
def test_loop_returns_to_the_start():
    T = synthetic_trajectory(40, "loop", step_m=0.15)
    steps = np.linalg.norm(np.diff(T[:, :3, 3], axis=0), axis=1)
    assert 0.1 < steps.mean() < 0.2
    closing = np.linalg.inv(T[-1]) @ T[0]  # one more step closes the loop
    assert np.linalg.norm(closing[:, 3][:3]) == pytest.approx(steps.mean(), rel=0.5)
    assert np.linalg.norm(T[:, :3, 3], axis=1).max() > 1.0  # and it did go somewhere
    seq = make_synthetic_sequence(n_frames=40, motion="loop")
    assert np.mean(np.abs(seq.left(0) - seq.left(39))) < np.mean(np.abs(seq.left(0) - seq.left(20)))


def test_turn_drives_straight_then_yaws_along_its_heading():
    from gtvo.datasets.synthetic import TURN_DEG_PER_FRAME, TURN_START_FRAME

    T = synthetic_trajectory(30, "turn", step_m=0.3)
    rel = np.linalg.inv(T[:-1]) @ T[1:]
    np.testing.assert_allclose(np.linalg.norm(rel[:, :3, 3], axis=1), 0.3, rtol=1e-12)
    yaw = np.degrees(np.arctan2(rel[:, 0, 2], rel[:, 2, 2]))  # rotation about the camera's y (down) axis
    np.testing.assert_allclose(yaw[:TURN_START_FRAME], 0.0, atol=1e-12)
    np.testing.assert_allclose(yaw[TURN_START_FRAME:], TURN_DEG_PER_FRAME, rtol=1e-9)
    np.testing.assert_allclose(rel[:, 1, :], np.broadcast_to([0, 1, 0, 0], (29, 4)), atol=1e-12)  # no pitch/roll/bob
    # each step goes along the new frame's optical axis: the path's heading is the camera's
    np.testing.assert_allclose(rel[:, :3, 3] / 0.3, rel[:, :3, 2], atol=1e-12)
    assert T[-1, 0, 3] > 2.0  # turned right (+x)


@pytest.mark.parametrize("kwargs", [dict(n_frames=0), dict(motion="circle"), dict(noise_sigma=-1.0),
                                    dict(noise_sigma=float("nan")), dict(width=8), dict(supersample=0),
                                    dict(baseline=0.0), dict(step_m=float("inf"))])
def test_bad_arguments_raise_input_error(kwargs):
    with pytest.raises(InputError):
        make_synthetic_sequence(**kwargs)


def test_render_refuses_a_camera_outside_the_room(seq):
    T = np.eye(4)
    T[0, 3] = 100.0
    with pytest.raises(InputError, match="outside the room"):
        seq.scene.render(T, seq.pinhole)
    with pytest.raises(InputError):
        seq.scene.render(np.full((4, 4), np.nan), seq.pinhole)


# ------------------------------------------------------------------------------------ exact depth


def test_depth_of_hand_computed_pixels(seq):
    scene, cam = seq.scene, seq.pinhole
    depth = seq.true_depth(0)
    # Frame 0 is the identity: a pixel near the centre looks at the back wall z = room_hi[2] (frontal plane).
    wall_z = 0.15 * 11 + 10.0  # the room reaches 10 m beyond the last camera centre (z = 11 steps)
    assert scene.room_hi[2] == pytest.approx(wall_z)
    assert depth[119, 159] == pytest.approx(wall_z, rel=1e-6)
    # The bottom row sees the ground y = room_hi[1]: z = y_ground * fy / (v - cy).
    ground_y = scene.room_hi[1]
    np.testing.assert_allclose(depth[239, 100:220], ground_y * cam.fy / (239 - cam.cy), rtol=1e-6)
    # A rotated, translated frame: ray-plane distance with the pose written out by hand.
    T = seq.gt_poses[9]
    u, v = 170, 110
    d_world = T[:3, :3] @ np.array([(u - cam.cx) / cam.fx, (v - cam.cy) / cam.fy, 1.0])
    t_wall = (wall_z - T[2, 3]) / d_world[2]
    assert seq.true_depth(9)[v, u] == pytest.approx(t_wall, rel=1e-6)
    # Right camera: same wall, camera shifted by the baseline along its own x axis.
    T_r = T.copy()
    T_r[:3, 3] += T[:3, 0] * seq.camera.baseline
    assert seq.true_depth(9, "right")[v, u] == pytest.approx((wall_z - T_r[2, 3]) / d_world[2], rel=1e-6)


@pytest.mark.slow
def test_box_faces_are_hit_with_the_right_depth():
    scene = SyntheticScene([-5, -5, -5], [5, 5, 20], [([-0.2, -0.2, 4], [0.2, 0.2, 6])], seed=0)
    cam = PinholeCamera(400, 400, 49.5, 49.5, 100, 100)  # corner rays: |x/z| = 0.124
    r = scene.render(np.eye(4), cam)
    assert r.depth[49, 49] == pytest.approx(4.0) and r.face[49, 49] == 6 + 2 * 2 + 0  # box face z = lo
    assert r.depth[0, 0] == pytest.approx(20.0) and r.face[0, 0] == 5  # room face z = hi
    # From the side (+x, looking back along -x) the box face x = hi is hit.
    T = np.eye(4)
    T[:3, :3] = np.array([[0, 0, -1], [0, 1, 0], [1, 0, 0]])  # camera z -> world -x
    T[:3, 3] = [4.0, 0.0, 5.0]
    r = scene.render(T, cam)
    assert r.depth[49, 49] == pytest.approx(3.8) and r.face[49, 49] == 6 + 2 * 0 + 1


def brute_force_hit(scene: SyntheticScene, o: np.ndarray, d: np.ndarray) -> tuple[float, int]:
    """Reference ray cast: intersect every face rectangle one by one, keep the nearest."""
    best_t, best_face = np.inf, -1
    for f, face in enumerate(scene.faces):
        k = face.axis
        if abs(d[k]) < 1e-12:
            continue
        t = (face.value - o[k]) / d[k]
        if t > 0 and t < best_t and on_face(scene, f, o + t * d):
            best_t, best_face = t, f
    return best_t, best_face


def on_face(scene: SyntheticScene, f: int, p: np.ndarray, tol: float = 1e-9) -> bool:
    """True when ``p`` lies on face ``f``'s rectangle."""
    face = scene.faces[f]
    lo, hi = (scene.room_lo, scene.room_hi) if f < 6 else scene.boxes[(f - 6) // 6]
    return abs(p[face.axis] - face.value) < tol and all(
        lo[a] - tol <= p[a] <= hi[a] + tol for a in range(3) if a != face.axis)


@settings(max_examples=40, deadline=None)
@given(st.floats(0.05, 0.95), st.floats(0.05, 0.95), st.floats(0.05, 0.95),
       st.floats(-1, 1), st.floats(-1, 1), st.floats(-1, 1))
def test_raycast_matches_a_brute_force_reference(scene_and_rays, fx, fy, fz, dx, dy, dz):
    scene, directions = scene_and_rays
    o = scene.room_lo + np.array([fx, fy, fz]) * (scene.room_hi - scene.room_lo)
    assume(scene.contains(o))
    rays = np.vstack([directions, [dx, dy, dz]])
    rays = rays[np.linalg.norm(rays, axis=1) > 1e-3]
    t, face = scene.raycast(o, rays)
    for i in range(rays.shape[0]):
        t_ref, f_ref = brute_force_hit(scene, o, rays[i])
        assert t[i] == pytest.approx(t_ref, rel=1e-9, abs=1e-9)
        if f_ref != face[i]:  # allowed only on an edge or corner, where the hit lies on both faces
            assert on_face(scene, int(face[i]), o + t[i] * rays[i], tol=1e-7)


@pytest.fixture(scope="module")
def scene_and_rays(seq):
    rng = np.random.default_rng(0)
    return seq.scene, rng.normal(size=(30, 3))


# ------------------------------------------------------------------------ photometric consistency


def test_subpixel_shift_matches_bilinear_sampling(seq):
    """Re-rendering with the principal point moved by (du, dv) shifts the image exactly; bilinear
    sampling of the original image must reproduce it on interior pixels."""
    cam = seq.pinhole
    du, dv = 0.5, 0.5  # the worst case for bilinear interpolation
    shifted = PinholeCamera(cam.fx, cam.fy, cam.cx + du, cam.cy + dv, cam.width, cam.height)
    render = seq.scene.render(seq.gt_poses[0], shifted)
    uv = pixel_grid(cam)
    val, ok = bilinear_sample(seq.left(0), uv[:, 0] - du, uv[:, 1] - dv, border=1)
    keep = ok & seq.interior_mask(0, margin=2).ravel()
    diff = np.abs(val - render.intensity.ravel())[keep]
    assert keep.mean() > 0.8
    assert np.median(diff) < 0.25 and np.percentile(diff, 90) < 1.5


@pytest.mark.parametrize("j", [1, 4])
def test_exact_depth_and_poses_warp_frame_onto_frame(seq, j):
    diff, n = warp_consistency(seq, 0, j)
    assert n > 20000
    assert np.median(diff) < 0.2 and np.percentile(diff, 90) < 1.0


def test_a_wrong_pose_breaks_the_consistency(seq):
    """The check above can fail: a 1 cm error in x already shows."""
    bad = make_synthetic_sequence(n_frames=12)
    bad.gt_poses = bad.gt_poses.copy()
    bad.gt_poses[4, 0, 3] += 0.01
    good, _ = warp_consistency(seq, 0, 4)
    wrong, _ = warp_consistency(bad, 0, 4)
    assert np.median(wrong) > 2 * np.median(good)


def test_stereo_consistency(seq):
    """Left pixel (u, v) at depth z appears in the right image at (u - fx * b / z, v)."""
    cam = seq.pinhole
    uv = pixel_grid(cam)
    z = seq.true_depth(3).ravel()
    u_r = uv[:, 0] - seq.camera.left.fx * seq.camera.baseline / z
    I_r, ok = bilinear_sample(seq.right(3), u_r, uv[:, 1], border=1)
    z_r, _ = bilinear_sample(seq.true_depth(3, "right"), u_r, uv[:, 1], border=1)
    keep = ok & (np.abs(z_r - z) < 0.01 * z) & seq.interior_mask(3).ravel()
    diff = np.abs(seq.left(3).ravel() - I_r)[keep]
    assert keep.sum() > 40000
    assert np.median(diff) < 0.1 and np.percentile(diff, 90) < 0.4


def test_texture_has_gradient_at_every_pyramid_level(seq):
    from gtvo.core.image import build_pyramid, image_gradients
    for level, img in enumerate(build_pyramid(seq.left(0), 4)):
        gx, gy = image_gradients(img)
        g = np.hypot(gx, gy)
        assert np.median(g) > 3.0, level  # gray levels per pixel (central differences)
        assert np.mean(g > 1.0) > 0.7, level
    assert 30 < seq.left(0).min() and seq.left(0).max() < 210  # headroom for exposure changes


# -------------------------------------------------------------------------- exposure and noise


def test_exposure_change_is_the_stated_affine_map():
    clean = make_synthetic_sequence(n_frames=8)
    lit = make_synthetic_sequence(n_frames=8, exposure_change=True)
    np.testing.assert_array_equal(lit.affine_left[0], [0.0, 0.0])
    assert np.ptp(lit.affine_left[:, 0]) > 0.05 and np.ptp(lit.affine_left[:, 1]) > 3.0
    for i in (0, 5):
        for side, image, clean_image in (("left", lit.left(i), clean.left(i)), ("right", lit.right(i), clean.right(i))):
            a, b = (lit.affine_left if side == "left" else lit.affine_right)[i]
            np.testing.assert_allclose(image, np.exp(a) * clean_image + b, atol=1e-3)
    assert not np.allclose(lit.affine_left, lit.affine_right)


def test_noise_has_the_stated_sigma_and_is_deterministic():
    clean = make_synthetic_sequence(n_frames=3)
    noisy = make_synthetic_sequence(n_frames=3, noise_sigma=3.0)
    r = noisy.left(2) - clean.left(2)
    assert np.std(r) == pytest.approx(3.0, rel=0.05) and abs(np.mean(r)) < 0.1
    assert not np.array_equal(noisy.left(1) - clean.left(1), r)  # fresh noise per frame
    assert not np.array_equal(noisy.right(2) - clean.right(2), r)  # and per side


# -------------------------------------------------------------------------------------- writer


def test_write_sequence_kitti(tmp_path):
    seq = make_synthetic_sequence(n_frames=3, exposure_change=True)
    out = write_sequence_kitti(seq, tmp_path / "seq")
    lines = (out / "calib.txt").read_text().splitlines()
    assert lines[0].startswith("P0: ") and lines[1].startswith("P1: ")
    P0 = np.array(lines[0].split()[1:], float).reshape(3, 4)
    P1 = np.array(lines[1].split()[1:], float).reshape(3, 4)
    np.testing.assert_allclose(P0[:, :3], seq.pinhole.K)
    assert -P1[0, 3] / P1[0, 0] == pytest.approx(seq.camera.baseline)
    for i in range(3):
        for sub, image in (("image_0", seq.left(i)), ("image_1", seq.right(i))):
            png = cv2.imread(str(out / sub / f"{i:06d}.png"), cv2.IMREAD_UNCHANGED)
            assert png.dtype == np.uint8
            np.testing.assert_array_equal(png, np.clip(np.rint(image), 0, 255).astype(np.uint8))
    poses = np.loadtxt(out / "poses.txt").reshape(3, 3, 4)
    np.testing.assert_allclose(poses, seq.gt_poses[:, :3, :], atol=1e-12)
    np.testing.assert_allclose(np.loadtxt(out / "times.txt"), seq.timestamps)
    assert [p.name for p in out.rglob(".*")] == [DIR_MARKER]  # no temporary files left behind, only the marker
    assert not [p.name for p in out.parent.iterdir() if p.name.startswith(".")]


def test_writer_refuses_a_non_stereo_sequence(tmp_path):
    rgbd = Sequence("rgbd", "rgbd", make_synthetic_sequence(n_frames=2).pinhole, [0.0, 0.1],
                    load_left=lambda i: np.zeros((240, 320), np.float32),
                    load_depth=lambda i: np.ones((240, 320), np.float32))
    with pytest.raises(InputError, match="not stereo"):
        write_sequence_kitti(rgbd, tmp_path)


def test_cli_command_writes_a_kitti_folder(tmp_path, capsys):
    import argparse

    from gtvo.commands import synthetic as command
    parser = argparse.ArgumentParser()
    command.register(parser.add_subparsers())
    args = parser.parse_args(["synthetic", "--out", str(tmp_path / "s"), "--frames", "2", "--motion", "loop"])
    assert args.func(args) == 0
    assert "wrote 2 stereo pairs" in capsys.readouterr().out
    assert sorted(p.name for p in (tmp_path / "s" / "image_1").iterdir()) == ["000000.png", "000001.png"]
    assert np.loadtxt(tmp_path / "s" / "poses.txt").shape == (2, 12)
    with pytest.raises(InputError):
        bad = parser.parse_args(["synthetic", "--out", str(tmp_path / "t"), "--frames", "0"])
        bad.func(bad)


def test_right_principal_offset_renders_a_shifted_right_image():
    """A right camera rendered with its principal point moved by (dx, dy) px sees the scene moved by
    exactly that (integer offsets: the images agree pixel for pixel); the left image is unchanged."""
    plain = make_synthetic_sequence(2, width=96, height=72)
    moved = make_synthetic_sequence(2, width=96, height=72, right_principal_offset=(2.0, -1.0))
    ra, rb = plain.right(1), moved.right(1)
    np.testing.assert_array_equal(rb[5:-5, 5:-5], ra[6:-4, 3:-7])
    np.testing.assert_array_equal(plain.left(1), moved.left(1))
    assert moved.camera == plain.camera
    with pytest.raises(InputError, match="right_principal_offset"):
        make_synthetic_sequence(2, width=96, height=72, right_principal_offset=(np.nan, 0.0))


def test_a_second_writer_of_one_synthetic_folder_is_refused(tmp_path, capsys):
    from gtvo import cli
    from gtvo.core.atomic import output_lock

    out = tmp_path / "seq"
    with output_lock(out):
        assert cli.main(["synthetic", "--out", str(out), "--frames", "2", "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "another gtvo process" in err, err
    assert cli.main(["synthetic", "--out", str(out), "--frames", "2", "--no-progress"]) == 0
    assert sorted(p.name for p in tmp_path.iterdir()) == ["seq"]
