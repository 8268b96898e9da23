"""When the window is optimised (gtvo/odometry/keyframer.py and window_schedule.py, ``WindowConfig.optimize_every``).

The window is optimised after every n-th keyframe that came from a successful track, at once for a
keyframe that did not (the first), and by ``VisualOdometry.finish()`` for the keyframes still
waiting at the end of the run; docs/window.md, "When the window is optimised".
"""

from __future__ import annotations

import numpy as np
import pytest

from gtvo.config import OdometryConfig
from gtvo.datasets.synthetic import make_synthetic_sequence
from gtvo.odometry import VisualOdometry
from gtvo.window import WindowConfig


@pytest.fixture(scope="module")
def forward():
    return make_synthetic_sequence(n_frames=40, step_m=0.2, noise_sigma=1.0, seed=3)


@pytest.fixture(scope="module")
def kitti(kitti_snippet):
    return kitti_snippet(max_frames=12)  # 1.2 m per frame: every frame becomes a keyframe


def _run(seq, every: int, finish: bool = True) -> VisualOdometry:
    vo = VisualOdometry(seq.camera, OdometryConfig(mode="window", window=WindowConfig(optimize_every=every,
                                                                                      covariances=False)))
    for frame in seq:
        vo.process(frame)
    if finish:
        vo.finish()
    return vo


@pytest.mark.slow
def test_every_keyframe_is_optimised_with_one(forward):
    vo = _run(forward, 1)
    assert len(vo.keyframes) >= 5
    # the first keyframe alone is no window; every later one triggered an optimisation
    assert len(vo.window_results) == len(vo.keyframes) - 1


@pytest.mark.slow
def test_frames_tracked_against_a_keyframe_make_it_optimised_at_once(forward):
    """On the synthetic room a keyframe comes every few frames: each has frames tracked against it,
    so no optimisation waits and the run is the one of ``optimize_every=1``, bit for bit."""
    one, three = _run(forward, 1), _run(forward, 3)
    assert len(three.window_results) == len(one.window_results)
    assert all(np.array_equal(a.T_world_cam, b.T_world_cam) for a, b in zip(one.estimates, three.estimates))


@pytest.mark.slow
@pytest.mark.realdata
def test_keyframes_at_every_frame_wait_and_finish_optimises_the_rest(kitti):
    vo = _run(kitti, 2, finish=False)
    n_kf = len(vo.keyframes)
    assert n_kf == len(kitti)  # every frame a keyframe
    waiting = vo.keyframer.schedule.waiting
    # the first keyframe (not tracked) optimises at once (alone: no window), then every second one
    assert len(vo.window_results) == (n_kf - 1) // 2 and waiting == (n_kf - 1) % 2
    before = vo.keyframes[-1].T_world_cam.matrix().copy()
    vo.finish()
    assert vo.keyframer.schedule.waiting == 0
    assert len(vo.window_results) == (n_kf - 1) // 2 + waiting
    if waiting:  # the waiting keyframe moved with the optimisation
        assert not np.allclose(before, vo.keyframes[-1].T_world_cam.matrix())
        assert np.array_equal(vo.estimates[-1].T_world_cam, vo.keyframes[-1].T_world_cam.matrix())
    n = len(vo.window_results)
    vo.finish()  # nothing waits: no new optimisation
    assert len(vo.window_results) == n


@pytest.mark.slow
@pytest.mark.realdata
def test_fewer_optimisations_keep_the_accuracy_on_kitti(kitti):
    every, second = _run(kitti, 1), _run(kitti, 2)
    assert len(second.window_results) < len(every.window_results)
    assert kitti.has_ground_truth
    err = {}
    for name, vo in (("every", every), ("second", second)):
        est = np.stack([e.T_world_cam for e in vo.estimates])[:, :3, 3]
        err[name] = float(np.sqrt(np.mean(np.sum((est - kitti.gt_poses[:, :3, 3]) ** 2, axis=1))))
    assert err["second"] < 1.5 * err["every"] + 0.01


@pytest.mark.slow
def test_finish_in_track_mode_does_nothing(forward):
    vo = VisualOdometry(forward.camera, OdometryConfig(mode="track"))
    for i in range(5):
        vo.process(forward.frame(i))
    poses = [e.T_world_cam.copy() for e in vo.estimates]
    vo.finish()
    assert all(np.array_equal(a, e.T_world_cam) for a, e in zip(poses, vo.estimates))


def test_optimize_every_must_be_positive():
    from gtvo.errors import InputError  # noqa: PLC0415

    with pytest.raises(InputError, match="optimize_every"):
        WindowConfig(optimize_every=0)


@pytest.mark.slow
@pytest.mark.realdata
def test_large_steps_optimise_every_keyframe(kitti_snippet):
    """At 5 Hz (2.4 m per frame) the new keyframe's stereo depth error moves its points by more than
    the pattern's radius over one step (about 2.5 px): each keyframe is optimised at once, and the
    run is the one of ``optimize_every=1``, bit for bit."""
    seq = kitti_snippet(max_frames=14).subsampled(2)
    one, two = _run(seq, 1), _run(seq, 2)
    assert len(two.window_results) == len(one.window_results) == len(seq) - 1
    assert all(np.array_equal(a.T_world_cam, b.T_world_cam) for a, b in zip(one.estimates, two.estimates))


@pytest.mark.slow
def test_a_keyframe_without_a_tracked_pyramid_builds_one_for_window_and_tracker(forward, monkeypatch):
    """The first keyframe (no tracking made its pyramid) builds the pyramid once: the window
    keyframe's left image is its level 0, not a second full-size GradientImage."""
    from factors.photometric import GradientImage  # noqa: PLC0415

    full = []
    init = GradientImage.__init__

    def counted(self, image, *args, **kwargs):
        if np.shape(image) == forward.camera.left.shape:
            full.append(np.shape(image))
        init(self, image, *args, **kwargs)

    monkeypatch.setattr(GradientImage, "__init__", counted)
    vo = VisualOdometry(forward.camera, OdometryConfig(mode="window", window=WindowConfig(covariances=False)))
    vo.process(next(iter(forward)))
    assert len(vo.keyframes) == 1
    assert len(full) == 2  # the left image's level 0 and the right image


def test_too_few_points_because_of_a_setting_names_the_setting(tmp_path, capsys):
    """A first frame refused because ``tracking.min_valid_points`` asks for more points than the
    front end selects: the error names the two keys, not the images or the calibration."""
    from gtvo import cli
    from gtvo.datasets.synthetic import make_synthetic_sequence, write_sequence_kitti

    log = write_sequence_kitti(make_synthetic_sequence(n_frames=2, width=160, height=120), tmp_path / "log")
    (tmp_path / "c.yaml").write_text("tracking: {min_valid_points: 100000}\n")
    assert cli.main(["run", str(log), "--out", str(tmp_path / "o"), "--no-progress", "--config",
                     str(tmp_path / "c.yaml")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "fewer than tracking.min_valid_points = 100000" in err, err
    assert "frontend.points_per_keyframe = 300" in err and "images may be blank" not in err, err
