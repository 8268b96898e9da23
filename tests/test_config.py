"""The configuration tree (gtvo/config/): one source of defaults, files in and out, checks that
name the key and the file, the CLI built on it, and a run reproduced from its recorded config."""

from __future__ import annotations

import dataclasses
import inspect
import json
import math
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

from factors.params import PhotometricConfig
from gtvo import cli
from gtvo.config import (FrontendConfig, KeyframeConfig, MotionModelConfig, OdometryConfig, SolverConfig,
                         as_config, config_from_dict, config_reference, config_to_dict, config_to_yaml, field_docs,
                         load_config)
from gtvo.core.settings import SettingError, in_range
from gtvo.datasets.identity import sequence_identity
from gtvo.datasets.synthetic import make_synthetic_sequence, write_sequence_kitti
from gtvo.errors import InputError
from gtvo.frontend import PointSelectionConfig, StereoSearchConfig, select_points, stereo_inverse_depth
from gtvo.frontend.flow_pose import FlowPoseConfig
from gtvo.frontend.stereo_depth import StereoDepthResult, matched_gain
from gtvo.frontend.tracking import TrackingConfig
from gtvo.motion.model import MotionNoiseConfig
from gtvo.window import WindowConfig

DOCS = Path(__file__).resolve().parents[1] / "docs" / "configuration.md"


def _odd_config() -> OdometryConfig:
    """A config away from the defaults in every kind of value: strings, ints, floats, inf, tuples,
    None sections, a pattern, a clip range switched off."""
    return OdometryConfig(
        mode="track", solver=SolverConfig(tracker="gtsam", window="handrolled"),
        frontend=FrontendConfig(points_per_keyframe=420, points=PointSelectionConfig(block=16, seed=3),
                                stereo=StereoSearchConfig(max_disparity=64, pattern="dso8", max_disparity_std=math.inf),
                                depth_sigma_model=(0.002, 0.003)),
        keyframes=KeyframeConfig(max_motion=0.1), tracking=TrackingConfig(max_rotation_sigma_deg=math.inf),
        window=WindowConfig(size=5, acceleration_sigma=None, backend="fixed_lag"), flow_fallback=None,
        motion_model=MotionModelConfig(model="kalman", accept_rms_factor=0.0,
                                       kalman_noise=MotionNoiseConfig(accel_sigmas=(2.0, 2.0, 0.0))),
        photometric=PhotometricConfig(sigma_intensity=6.5, huber_k=None, pattern=((0, 0), (1, 0), (0, 1)),
                                      clip_range=None))


# -- the tree ------------------------------------------------------------------------------------
def test_plain_data_round_trip_is_exact_through_json_and_yaml(tmp_path):
    for cfg in (OdometryConfig(), _odd_config()):
        d = config_to_dict(cfg)
        assert config_to_dict(config_from_dict(json.loads(json.dumps(d)))) == d
        (tmp_path / "c.yaml").write_text(config_to_yaml(cfg, "header"))
        assert config_to_dict(load_config(tmp_path / "c.yaml")) == d
        (tmp_path / "c.json").write_text(json.dumps(d))
        assert config_to_dict(load_config(tmp_path / "c.json")) == d
    odd = load_config(tmp_path / "c.json")
    assert odd.motion_model.kalman_noise.accel_sigmas == (2.0, 2.0, 0.0)
    assert odd.frontend.stereo.max_disparity_std == math.inf and odd.flow_fallback is None
    assert odd.window.acceleration_sigma is None and odd.photometric.clip_range is None


def test_names_as_shorthands_and_the_readme_form():
    # a solver name is the tracker's, as before the tree; the window keeps its default (GTSAM)
    assert OdometryConfig(solver="handrolled").solver == SolverConfig("handrolled", "gtsam")
    assert SolverConfig.both("handrolled") == SolverConfig("handrolled", "handrolled")  # the CLI's --solver
    assert OdometryConfig(motion_model="kalman").motion_model == MotionModelConfig(model="kalman")
    cfg = OdometryConfig(mode="window", solver="gtsam")  # README.md
    assert (cfg.mode, cfg.solver.tracker, cfg.solver.window) == ("window", "gtsam", "gtsam")
    assert config_from_dict({"motion_model": "kalman"}).motion_model.model == "kalman"
    with pytest.raises(InputError, match="key 'solver': must be a mapping"):
        config_from_dict({"solver": "handrolled"})  # a file names the tracker's and the window's


def test_flat_names_before_the_tree_are_aliases_of_their_keys():
    from gtvo.config import LEGACY_NAMES  # noqa: PLC0415

    cfg = OdometryConfig(mode="track", points_per_keyframe=150, keyframe_max_motion=0.02, window_solver="handrolled",
                         max_disparity=64, depth_sigma_model=(0.001, 0.002), accept_rms_factor=0.0)
    assert cfg.frontend.points_per_keyframe == cfg.points_per_keyframe == 150 and cfg.mode == "track"
    assert cfg.keyframes.max_motion == cfg.keyframe_max_motion == 0.02
    assert cfg.solver == SolverConfig("handrolled", "handrolled") and cfg.window_solver == "handrolled"
    assert cfg.frontend.stereo.max_disparity == cfg.max_disparity == 64
    assert cfg.frontend.depth_sigma_model == (0.001, 0.002) and cfg.motion_model.accept_rms_factor == 0.0
    default = OdometryConfig()
    for name, key in LEGACY_NAMES.items():  # every alias reads its key
        value = default
        for part in key.split("."):
            value = getattr(value, part)
        assert getattr(default, name) == value, name
    with pytest.raises(InputError, match="frontend.points_per_keyframe: must be >= 50"):
        OdometryConfig(points_per_keyframe=10)
    with pytest.raises(InputError, match="key 'points_per_keyframe': unknown key"):
        config_from_dict({"points_per_keyframe": 300})  # files use the keys
    assert dataclasses.replace(cfg, mode="window").points_per_keyframe == 150


def test_library_defaults_are_the_single_source():
    cfg = OdometryConfig()
    assert (cfg.solver.tracker, cfg.solver.window) == ("handrolled", "gtsam")
    # the front-end functions' keyword defaults are their config's
    for func, cls in ((select_points, PointSelectionConfig), (stereo_inverse_depth, StereoSearchConfig)):
        params = inspect.signature(func).parameters
        for f in dataclasses.fields(cls):
            assert params[f.name].default == getattr(cls(), f.name), (func.__name__, f.name)
    # the tracker's and the window's photometric settings are photometric's
    p = PhotometricConfig()
    for sub in (cfg.tracking, cfg.window):
        assert sub.sigma_intensity == p.sigma_intensity and sub.huber_k == p.huber_k
        np.testing.assert_array_equal(sub.pattern, p.pattern_array)
    assert cfg.tracking.clip_range == p.clip_range == (0.0, 255.0)


def test_photometric_reaches_tracker_and_window_and_has_one_source():
    p = PhotometricConfig(sigma_intensity=5.0, huber_k=2.0, pattern=((0, 0), (1, 1)), clip_range=(2.0, 250.0))
    cfg = OdometryConfig(photometric=p)
    for sub in (cfg.tracking, cfg.window):
        assert sub.sigma_intensity == 5.0 and sub.huber_k == 2.0 and sub.pattern.tolist() == [[0, 0], [1, 1]]
    assert cfg.tracking.clip_range == (2.0, 250.0)
    with pytest.raises(InputError, match="tracking.huber_k.*photometric.huber_k"):
        OdometryConfig(tracking=TrackingConfig(huber_k=2.0))
    back = dataclasses.replace(cfg, photometric=PhotometricConfig())  # the copies follow a new photometric
    assert back.tracking.huber_k == back.window.huber_k == PhotometricConfig().huber_k
    with pytest.raises(InputError, match="key 'window.sigma_intensity': is set by photometric"):
        config_from_dict({"window": {"sigma_intensity": 4.0}})


def test_clip_range_of_the_config_reaches_every_image_of_a_run():
    seq = make_synthetic_sequence(n_frames=2, width=160, height=120)
    from gtvo.odometry import VisualOdometry  # noqa: PLC0415

    for clip in ((0.0, 255.0), None, (10.0, 240.0)):
        vo = VisualOdometry(seq.camera, OdometryConfig(photometric=PhotometricConfig(clip_range=clip)))
        for frame in seq:
            vo.process(frame)
        assert vo.keyframes[-1].tracker is not None and vo.keyframes[-1].tracker.config.clip_range == clip
        assert all(w.image.clip_range == clip and w.right.clip_range == clip for w in vo.window.keyframes)


def test_matched_gain_leaves_out_clipped_patches_only_with_a_clip_range():
    rng = np.random.default_rng(0)
    left = rng.uniform(20, 100, (60, 80)).astype(np.float32)
    left[:, 32:] += 60.0  # a bright right part, which the brighter camera below saturates
    right = np.minimum(left * 2.2, 255.0)
    px = np.array([[u, v] for v in range(10, 50, 4) for u in range(10, 70, 4)], dtype=float)
    n = len(px)
    res = StereoDepthResult(np.ones(n), np.ones(n), np.ones(n, bool), np.zeros(n), np.zeros(n), np.ones(n),
                            np.zeros(n, np.int8))
    unclipped = matched_gain(left, right, px, res, clip_range=None)
    clipped = matched_gain(left, right, px, res)
    assert clipped == pytest.approx(2.2, rel=1e-4) and unclipped < 1.5


def test_settings_name_the_field_and_ranges_parse():
    with pytest.raises(SettingError, match="^size: must be >= 2, got 1$"):
        WindowConfig(size=1)
    with pytest.raises(SettingError, match="downweight: must be in \\(0, 1\\]"):
        PointSelectionConfig(downweight=0.0)
    with pytest.raises(SettingError, match="pattern: must be one of 'patch5x5', 'dso8'"):
        StereoSearchConfig(pattern="square")
    with pytest.raises(SettingError, match="min_inliers"):
        FlowPoseConfig(min_inliers=2)
    with pytest.raises(InputError, match="frontend: must be a FrontendConfig"):
        OdometryConfig(frontend={"points_per_keyframe": 300})
    assert in_range(1.0, "(0, 1]") and not in_range(0.0, "(0, 1]") and not in_range(float("nan"), ">= 0")
    assert in_range(math.inf, "> 0") and not in_range(2.0, "[0, 2)")


def test_as_config_takes_a_tree_a_file_or_the_object(tmp_path):
    (tmp_path / "c.yaml").write_text("mode: track\nfrontend: {points_per_keyframe: 500}\n")
    for value in ({"mode": "track", "frontend": {"points_per_keyframe": 500}}, tmp_path / "c.yaml",
                  str(tmp_path / "c.yaml")):
        cfg = as_config(value)
        assert cfg.mode == "track" and cfg.frontend.points_per_keyframe == 500 and cfg.window.size == 7
    assert config_to_dict(as_config(None)) == config_to_dict(OdometryConfig())
    with pytest.raises(InputError):
        as_config(42)


# -- bad files: one line naming the key and the file, exit 2 ------------------------------------
@pytest.mark.parametrize("text,needle", [
    ("window:\n  sise: 3\n", "key 'window.sise': unknown key (did you mean 'size'?)"),
    ("colour: red\n", "key 'colour': unknown key"),
    ("window:\n  size: seven\n", "key 'window.size': must be an integer, got 'seven' (str)"),
    ("frontend: {stereo: {left_right_check: 1}}\n", "key 'frontend.stereo.left_right_check': must be true or false"),
    ("keyframes: {max_motion: [1, 2]}\n", "key 'keyframes.max_motion': must be a number"),
    ("window: 7\n", "key 'window': must be a mapping of keys"),
    ("window:\n  size: 1\n", "key 'window.size': must be >= 2, got 1"),
    ("keyframes: {min_visible: 1.5}\n", "key 'keyframes.min_visible': must be in [0, 1], got 1.5"),
    ("mode: batch\n", "key 'mode': must be one of 'track', 'window', got 'batch'"),
    ("solver: {window: ceres}\n", "key 'solver.window': must be one of 'handrolled', 'gtsam', got 'ceres'"),
    ("frontend: {stereo: {min_disparity: 50, max_disparity: 40}}\n", "key 'frontend.stereo': min_disparity (50)"),
    ("window: [size: 1\n", ":2: not valid YAML"),
    ("- 1\n- 2\n", "key '(top level)': must be a mapping of keys"),
])
def test_bad_config_file_one_line_exit_2(tmp_path, capsys, text, needle):
    bad = tmp_path / "bad.yaml"
    bad.write_text(text)
    assert cli.main(["demo", "--out", str(tmp_path / "o"), "--config", str(bad), "--no-progress"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and needle in err[0] and str(bad) in err[0], err
    assert not (tmp_path / "o").exists()


def test_missing_config_file_exit_2(tmp_path, capsys):
    assert cli.main(["demo", "--out", str(tmp_path / "o"), "--config", str(tmp_path / "nope.yaml")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "nope.yaml" in err[0]


# -- the CLI on the tree -------------------------------------------------------------------------
def _resolved(argv):
    from gtvo.commands._common import odometry_config  # noqa: PLC0415

    return odometry_config(cli.build_parser().parse_args(argv))


def test_cli_defaults_are_the_library_defaults_and_flags_override_the_file(tmp_path):
    assert config_to_dict(_resolved(["run", "SEQ"])) == config_to_dict(OdometryConfig())
    f = tmp_path / "c.yaml"
    f.write_text("mode: track\nfrontend: {points_per_keyframe: 500}\nsolver: {tracker: gtsam}\n")
    cfg = _resolved(["run", "SEQ", "--config", str(f), "--points", "600"])
    assert cfg.mode == "track" and cfg.frontend.points_per_keyframe == 600 and cfg.solver.tracker == "gtsam"
    cfg = _resolved(["run", "SEQ", "--config", str(f), "--solver", "handrolled", "--mode", "window",
                     "--window-backend", "fixed-lag", "--motion-model", "kalman"])
    assert cfg.solver == SolverConfig("handrolled", "handrolled") and cfg.window.backend == "fixed_lag"
    assert cfg.mode == "window" and cfg.motion_model.model == "kalman" and cfg.frontend.points_per_keyframe == 500
    # demo keeps its own points default under a partial file
    (tmp_path / "d.yaml").write_text("mode: track\n")
    assert _resolved(["demo", "--config", str(tmp_path / "d.yaml")]).frontend.points_per_keyframe == 800


def test_cli_help_comes_from_the_dataclasses():
    parser = cli.build_parser()
    run = next(a for a in parser._actions if a.dest == "command").choices["run"]
    helps = {a.option_strings[0]: a.help for a in run._actions if a.option_strings}
    doc = field_docs(FrontendConfig)["points_per_keyframe"].replace("%", "%%")
    assert doc.rstrip(".") in helps["--points"]
    assert f"default: {FrontendConfig().points_per_keyframe})" in helps["--points"]
    assert field_docs(OdometryConfig)["mode"].rstrip(".") in helps["--mode"]
    solver = OdometryConfig().solver
    assert f"{solver.tracker} tracker, {solver.window} window" in helps["--solver"]


def test_docs_list_every_key():
    """docs/configuration.md holds :func:`config_reference`'s table as it is now (regenerate with
    ``python -c "from gtvo.config import config_reference; print(config_reference())"``)."""
    table = config_reference()
    assert table in DOCS.read_text(), "docs/configuration.md is out of date"
    keys = []

    def walk(d, path):
        for k, v in d.items():
            keys.append(f"{path}{k}")
            if isinstance(v, dict):
                walk(v, f"{path}{k}.")

    walk(config_to_dict(OdometryConfig()), "")
    assert all(f"| `{k}` |" in table for k in keys)


# -- input identity ------------------------------------------------------------------------------
def test_sequence_identity_follows_the_frames_not_the_folder(tmp_path):
    a = tmp_path / "a"
    write_sequence_kitti(make_synthetic_sequence(n_frames=3, width=64, height=48), a)
    from gtvo.datasets import open_sequence  # noqa: PLC0415

    ida = sequence_identity(open_sequence(a), "kitti")
    assert ida["frames"] == 3 and ida["first_frame"] == "image_0/000000.png" and len(ida["sha256"]) == 64
    b = tmp_path / "elsewhere" / "a"
    shutil.copytree(a, b)
    assert sequence_identity(open_sequence(b), "kitti")["sha256"] == ida["sha256"]
    assert sequence_identity(open_sequence(b, max_frames=2), "kitti")["sha256"] != ida["sha256"]
    times = (b / "times.txt").read_text().split()
    (b / "times.txt").write_text("\n".join(times[:-1] + [str(float(times[-1]) + 0.01)]) + "\n")
    assert sequence_identity(open_sequence(b), "kitti")["sha256"] != ida["sha256"]
    shutil.copy(a / "times.txt", b / "times.txt")
    first = b / "image_0" / "000000.png"
    first.write_bytes(first.read_bytes() + b"\0")
    assert sequence_identity(open_sequence(b), "kitti")["sha256"] != ida["sha256"]


# -- a run reproduced from its report ----------------------------------------------------------
def _gtvo(*args):
    return subprocess.run([sys.executable, "-m", "gtvo", *map(str, args)], capture_output=True, text=True, timeout=600)


@pytest.mark.slow
def test_report_config_reproduces_the_trajectory_to_the_bit(tmp_path):
    seq = tmp_path / "seq"
    write_sequence_kitti(make_synthetic_sequence(n_frames=6, width=160, height=120), seq)
    r = _gtvo("run", seq, "--out", tmp_path / "a", "--no-progress", "--points", "250", "--motion-model", "kalman")
    assert r.returncode == 0, r.stderr
    rep = json.loads((tmp_path / "a" / "report.json").read_text())
    assert rep["gtvo_version"] and rep["input"]["frames"] == 6 and rep["input"]["format"] == "kitti"
    assert rep["config"]["frontend"]["points_per_keyframe"] == 250  # flags are recorded
    assert rep["config"]["motion_model"]["model"] == "kalman" and rep["window_solver"] == "gtsam"
    assert yaml.safe_load((tmp_path / "a" / "config.yaml").read_text()) is not None
    (tmp_path / "from_report.json").write_text(json.dumps(rep["config"]))
    r = _gtvo("run", seq, "--out", tmp_path / "b", "--no-progress", "--config", tmp_path / "from_report.json")
    assert r.returncode == 0, r.stderr
    assert (tmp_path / "b" / "trajectory.tum").read_bytes() == (tmp_path / "a" / "trajectory.tum").read_bytes()
    rep_b = json.loads((tmp_path / "b" / "report.json").read_text())
    assert rep_b["config"] == rep["config"] and rep_b["input"] == rep["input"]
    # the library reads the written config.yaml the same way
    import gtvo  # noqa: PLC0415

    rep_c = gtvo.run(seq, out=tmp_path / "c", config=tmp_path / "a" / "config.yaml")
    assert rep_c["config"] == rep["config"]
    assert (tmp_path / "c" / "trajectory.tum").read_bytes() == (tmp_path / "a" / "trajectory.tum").read_bytes()


def test_kalman_settings_reach_the_filter():
    from gtvo.odometry import VisualOdometry  # noqa: PLC0415

    seq = make_synthetic_sequence(n_frames=1, width=160, height=120)
    mm = MotionModelConfig(model="kalman", kalman_noise=MotionNoiseConfig(accel_sigmas=(3.0, 3.0, 1.0)),
                           kalman_initial_rate_sigmas=(2.0, 2.0, 0.25))
    vo = VisualOdometry(seq.camera, OdometryConfig(motion_model=mm))
    assert vo._kalman.noise.accel_sigmas == (3.0, 3.0, 1.0)
    assert vo._kalman.initial_rate_sigmas == (2.0, 2.0, 0.25)
    with pytest.raises(InputError, match="key 'motion_model.kalman_initial_rate_sigmas': must be > 0"):
        config_from_dict({"motion_model": {"kalman_initial_rate_sigmas": [1, 1, 0]}})
