import re

import numpy as np
import pytest

from gtvo.core.camera import PinholeCamera, StereoCamera
from gtvo.errors import InputError


def make_cam():
    return PinholeCamera(fx=500.0, fy=400.0, cx=320.0, cy=240.0, width=640, height=480)


def test_project_hand_computed():
    cam = make_cam()
    uv, ok = cam.project([[1.0, -0.5, 2.0], [0.0, 0.0, 1.0]])
    # u = 500 * 1/2 + 320 = 570, v = 400 * -0.25 + 240 = 140
    np.testing.assert_allclose(uv, [[570.0, 140.0], [320.0, 240.0]])
    assert ok.all()


def test_behind_camera_masked_not_nan():
    cam = make_cam()
    uv, ok = cam.project([[1.0, 1.0, -2.0], [1.0, 1.0, 0.0]])
    assert not ok.any()
    assert np.all(np.isfinite(uv))


def test_backproject_roundtrip():
    rng = np.random.default_rng(0)
    cam = make_cam()
    P = rng.uniform([-2, -2, 0.5], [2, 2, 20], size=(100, 3))
    uv, _ = cam.project(P)
    np.testing.assert_allclose(cam.backproject(uv, P[:, 2]), P, rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(cam.backproject_inverse_depth(uv, 1 / P[:, 2]), P, rtol=1e-10, atol=1e-12)


def test_K_and_inverse():
    cam = make_cam()
    np.testing.assert_allclose(cam.K @ cam.K_inv, np.eye(3), atol=1e-15)
    assert PinholeCamera.from_matrix(cam.K, 640, 480) == cam


def test_scaled_matches_block_average_centres():
    cam = make_cam()
    c1 = cam.scaled(1)
    # pixels 0 and 1 of level 0 average into pixel 0 of level 1, whose centre is u0 = 0.5
    assert c1.fx == 250.0 and c1.cx == (320.0 + 0.5) / 2 - 0.5
    assert (c1.width, c1.height) == (320, 240)
    P = np.array([[0.3, -0.2, 3.0]])
    uv0, _ = cam.project(P)
    uv1, _ = c1.project(P)
    np.testing.assert_allclose(uv1, (uv0 + 0.5) / 2 - 0.5)


def test_stereo_disparity():
    st = StereoCamera(make_cam(), baseline=0.5)
    P = np.array([[0.2, 0.1, 5.0]])
    uvl, _ = st.left.project(P)
    uvr, _ = st.project_right(P)
    disp = uvl[0, 0] - uvr[0, 0]
    assert disp == pytest.approx(500 * 0.5 / 5.0)
    assert st.inverse_depth_from_disparity(disp) == pytest.approx(0.2)
    np.testing.assert_allclose(st.T_right_left @ np.r_[P[0], 1.0], [0.2 - 0.5, 0.1, 5.0, 1.0])


@pytest.mark.parametrize("kwargs", [dict(fx=0.0), dict(fy=float("nan")), dict(width=0), dict(cx=float("inf"))])
def test_bad_intrinsics_rejected(kwargs):
    base = dict(fx=500.0, fy=400.0, cx=320.0, cy=240.0, width=640, height=480)
    base.update(kwargs)
    with pytest.raises(InputError):
        PinholeCamera(**base)


@pytest.mark.parametrize("cx,cy,ok", [(320.0, 240.0, True), (-0.5, 479.5, True), (639.5, -0.5, True),
                                       (640.5, 480.5, True), (-0.6, 240.0, False), (640.6, 240.0, False),
                                       (240.0, 481.0, False), (240.0, 320.0 * 2, False)])
def test_principal_point_must_lie_on_the_image(cx, cy, ok):
    """A principal point off the image is a misread or mismatched calibration: refused by name.
    Half a pixel of slack past the far edge keeps every pyramid level of an accepted camera valid."""
    if ok:
        PinholeCamera(500.0, 500.0, cx, cy, 640, 480)
    else:
        with pytest.raises(InputError, match=r"principal point .* outside the 640x480 image"):
            PinholeCamera(500.0, 500.0, cx, cy, 640, 480)


def test_every_pyramid_level_of_an_accepted_camera_is_accepted():
    """scaled() rounds the size down but not cx: the reviewer's case, cx near an odd far edge."""
    for cam in (PinholeCamera(700.0, 700.0, 1240.5, 375.5, 1241, 376), PinholeCamera(100.0, 100.0, 8.5, 8.5, 9, 9),
                PinholeCamera(100.0, 100.0, -0.5, -0.5, 9, 9)):
        for level in range(4):
            if min(cam.width >> level, cam.height >> level) > 0:
                cam.scaled(level)


def test_bad_baseline_rejected():
    with pytest.raises(InputError, match="baseline"):
        StereoCamera(make_cam(), baseline=-0.1)


@pytest.mark.parametrize("fx,fy,needle", [(1e300, 500.0, "camera fx = 1e+300 px is implausible for an image 640 px wide"),
                                          (1e-300, 500.0, "camera fx = 1e-300 px is implausible"),
                                          (500.0, 1e-3, "camera fy = 0.001 px is implausible for an image 480 px high"),
                                          (500.0, 1e7, "field of view of 0.00275 degrees")])
def test_a_focal_length_no_pinhole_camera_has_is_refused_naming_it(fx, fy, needle):
    """Finite and positive is not enough: 1e300 px (a field of view of ~0) overflows the tracker's
    normal equations, 1e-300 px (~180 degrees) makes them vanish."""
    with pytest.raises(InputError, match=re.escape(needle)) as info:
        PinholeCamera(fx, fy, 320.0, 240.0, 640, 480)
    assert "\n" not in str(info.value)


def test_plausible_focal_lengths_stay_accepted_at_every_pyramid_level():
    for cam in (PinholeCamera(5000.0, 5000.0, 320.0, 240.0, 640, 480),  # a telephoto: 7.3 degrees
                PinholeCamera(100.0, 100.0, 320.0, 240.0, 640, 480)):  # a wide angle: 145 degrees
        for level in range(4):
            cam.scaled(level)
