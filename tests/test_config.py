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
    # a solver name is both solvers', as --solver NAME is (and a file's solver: NAME)
    assert OdometryConfig(solver="handrolled").solver == SolverConfig("handrolled", "handrolled")
    assert SolverConfig.both("handrolled") == SolverConfig("handrolled", "handrolled")  # the CLI's --solver
    assert config_from_dict({"solver": "handrolled"}).solver == SolverConfig("handrolled", "handrolled")
    assert OdometryConfig(motion_model="kalman").motion_model == MotionModelConfig(model="kalman")
    cfg = OdometryConfig(mode="window", solver="gtsam")  # README.md
    assert (cfg.mode, cfg.solver.tracker, cfg.solver.window) == ("window", "gtsam", "gtsam")
    assert config_from_dict({"motion_model": "kalman"}).motion_model.model == "kalman"
    mixed = OdometryConfig(solver=SolverConfig(tracker="gtsam", window="handrolled"))  # mixed: the object
    assert (mixed.solver.tracker, mixed.solver.window) == ("gtsam", "handrolled")


@pytest.mark.parametrize("name", ["points_per_keyframe", "keyframe_max_motion", "window_solver", "max_disparity",
                                  "accept_rms_factor"])
def test_the_flat_names_before_the_tree_are_gone(tmp_path, capsys, name):
    from gtvo.config import MOVED_KEYS  # noqa: PLC0415

    assert not hasattr(OdometryConfig(), name)
    with pytest.raises(TypeError):
        OdometryConfig(**{name: 1})
    # a config file that still uses one is told the key that holds it now: one line, exit 2
    bad = tmp_path / "old.yaml"
    bad.write_text(f"{name}: 1\n")
    assert cli.main(["demo", "--out", str(tmp_path / "o"), "--config", str(bad), "--no-progress"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and str(bad) in err[0] and f"key '{name}': is now key '{MOVED_KEYS[name]}'" in err[0], err


def test_library_defaults_are_the_single_source():
    cfg = OdometryConfig()
    assert (cfg.solver.tracker, cfg.solver.window) == ("handrolled", "gtsam")
    # the front-end functions take their config whole, its defaults by default
    for func, cls in ((select_points, PointSelectionConfig), (stereo_inverse_depth, StereoSearchConfig)):
        params = inspect.signature(func).parameters
        assert params["config"].default == cls() and not set(params) & {f.name for f in dataclasses.fields(cls)}
    # the tracker and the window have no photometric settings of their own: photometric holds them
    for section in (TrackingConfig, WindowConfig):
        assert not {f.name for f in dataclasses.fields(section)} & {f.name for f in dataclasses.fields(PhotometricConfig)}


def test_photometric_reaches_tracker_and_window_as_one_object():
    from gtvo.odometry import VisualOdometry  # noqa: PLC0415

    seq = make_synthetic_sequence(n_frames=2, width=160, height=120)
    p = PhotometricConfig(sigma_intensity=5.0, huber_k=2.0, pattern=((0, 0), (1, 1)), clip_range=(2.0, 250.0))
    vo = VisualOdometry(seq.camera, OdometryConfig(photometric=p))
    for frame in seq:
        vo.process(frame)
    assert vo.window is not None and vo.window.optimizer.photometric is p
    assert vo.keyframes[-1].tracker is not None and vo.keyframes[-1].tracker.photometric is p
    assert vo.keyframes[-1].tracker.pattern.tolist() == [[0, 0], [1, 1]]
    with pytest.raises(TypeError):
        TrackingConfig(huber_k=2.0)  # type: ignore[call-arg]
    for section in ("tracking", "window"):
        with pytest.raises(InputError, match=f"key '{section}.sigma_intensity': is now key 'photometric.sigma_intensity'"):
            config_from_dict({section: {"sigma_intensity": 4.0}})


def test_clip_range_of_the_config_reaches_every_image_of_a_run():
    seq = make_synthetic_sequence(n_frames=2, width=160, height=120)
    from gtvo.odometry import VisualOdometry  # noqa: PLC0415

    for clip in ((0.0, 255.0), None, (10.0, 240.0)):
        vo = VisualOdometry(seq.camera, OdometryConfig(photometric=PhotometricConfig(clip_range=clip)))
        for frame in seq:
            vo.process(frame)
        assert vo.keyframes[-1].tracker is not None and vo.keyframes[-1].tracker.photometric.clip_range == clip
        assert all(w.image.clip_range == clip and w.right.clip_range == clip for w in vo.window.optimizer.keyframes)


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
    with pytest.raises(SettingError, match="^size: must be in \\[2, 100\\], got 1$"):
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
    assert not in_range(2.0, "[0, 2)")
    # infinity only where the range names it: "(0, inf]" (a check switched off), never "> 0"
    assert not in_range(math.inf, "> 0") and not in_range(-math.inf, "<= 0") and in_range(math.inf, "(0, inf]")


def test_every_numeric_setting_has_a_finite_range():
    """Each number of the tree has a range with two finite ends, or infinity as a named, closed
    end (``[0, inf]``: the check switched off); the pattern's offsets are checked by
    PhotometricConfig (within +-8 px)."""
    from gtvo.core.settings import dataclass_of, parse_range, type_hints  # noqa: PLC0415

    numeric, unbounded = [], []

    def walk(cls, path):
        hints = type_hints(cls)
        for f in dataclasses.fields(cls):
            sub = dataclass_of(hints[f.name])
            if sub is not None:
                walk(sub, f"{path}{f.name}.")
            elif {int, float} & set(_leaf_types(hints[f.name])) and f"{path}{f.name}" != "photometric.pattern":
                numeric.append(f"{path}{f.name}")
                rng = f.metadata.get("range")
                lo, hi, lo_closed, hi_closed = parse_range(rng) if rng else (-math.inf, math.inf, False, False)
                if not (math.isfinite(lo) or lo_closed) or not (math.isfinite(hi) or hi_closed):
                    unbounded.append(f"{path}{f.name}")

    walk(OdometryConfig, "")
    assert len(numeric) > 80 and not unbounded, unbounded


def _leaf_types(hint):
    import typing  # noqa: PLC0415

    args = typing.get_args(hint)
    return [hint] if not args else [t for a in args for t in _leaf_types(a)]


@pytest.mark.slow
def test_loop_closure_is_a_section_of_the_tree(tmp_path, monkeypatch):
    from gtvo.loops import LoopClosureConfig, LoopDetectorConfig  # noqa: PLC0415
    import gtvo.loops.closing as closing  # noqa: PLC0415
    from gtvo.pipeline import run  # noqa: PLC0415

    cfg = config_from_dict({"loops": {"enabled": True, "detector": {"n_words": 300, "verification": {"min_inliers": 20}}}})
    assert cfg.loops == LoopClosureConfig(True, LoopDetectorConfig(n_words=300, verification=cfg.loops.detector.verification))
    assert cfg.loops.detector.verification.min_inliers == 20 and not OdometryConfig().loops.enabled
    seen = []

    def spy(seq, est, *args, **kwargs):  # what the run hands to loop closing
        seen.append(kwargs)
        return closing.LoopClosingResult(est)

    monkeypatch.setattr(closing, "close_loops_of_run", spy)
    seq = make_synthetic_sequence(n_frames=3, width=160, height=120)
    (tmp_path / "c.yaml").write_text("loops: {enabled: true, detector: {n_words: 300}}\n")
    rep = run(seq, out=tmp_path / "file", config=tmp_path / "c.yaml")  # from --config alone
    assert len(seen) == 1 and seen[0]["detector_config"].n_words == 300
    assert rep["config"]["loops"]["enabled"] is True and rep["config"]["loops"]["detector"]["n_words"] == 300
    assert load_config(tmp_path / "file" / "config.yaml").loops == cfg.loops.__class__(True, LoopDetectorConfig(n_words=300))
    rep = run(seq, out=tmp_path / "flag", loop_closure=True)  # gtvo.run(loop_closure=True), as --loop-closure
    assert len(seen) == 2 and rep["config"]["loops"]["enabled"] is True
    assert load_config(tmp_path / "flag" / "config.yaml").loops.enabled
    rep = run(seq, out=tmp_path / "off")
    assert len(seen) == 2 and rep["config"]["loops"]["enabled"] is False and "loops_detected" not in rep
    args = cli.build_parser().parse_args(["run", "SEQ", "--loop-closure"])
    assert args.loop_closure  # handed to gtvo.run(loop_closure=...), which sets loops.enabled


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
    ("window:\n  size: 1\n", "key 'window.size': must be in [2, 100], got 1"),
    ("keyframes: {min_visible: 1.5}\n", "key 'keyframes.min_visible': must be in [0, 1], got 1.5"),
    ("mode: batch\n", "key 'mode': must be one of 'track', 'window', got 'batch'"),
    ("solver: {window: ceres}\n", "key 'solver.window': must be one of 'handrolled', 'gtsam', got 'ceres'"),
    ("frontend: {stereo: {min_disparity: 50, max_disparity: 40}}\n",
     "key 'frontend.stereo.max_disparity': must be above min_disparity (50), got 40"),
    # ranges that mean something: finite, a sensible interval (issue 31)
    ("photometric:\n  sigma_intensity: 1.0e-300\n", "key 'photometric.sigma_intensity': must be in [0.01, 100], got 1e-300"),
    ("photometric: {huber_k: .inf}\n", "key 'photometric.huber_k': must be in [0.01, 100], got inf"),
    ("keyframes: {max_motion: .nan}\n", "key 'keyframes.max_motion': must be in [0, inf], got nan"),
    ("window: {gauge_sigma: 1.0e-300}\n", "key 'window.gauge_sigma': must be in [1e-9, 1], got 1e-300"),
    ("frontend: {points: {seed: -1}}\n", "key 'frontend.points.seed': must be in [0, 4294967295], got -1"),
    ("tracking: {levels: 40}\n", "key 'tracking.levels': must be in [1, 10], got 40"),
    ("photometric: {pattern: [[0, 0], [30, 0]]}\n", "key 'photometric.pattern': must be a list of (du, dv) offsets"),
    ("loops: {detector: {orb: {scale_factor: 3.0}}}\n", "key 'loops.detector.orb.scale_factor': must be in (1, 2]"),
    # a key given twice: refused, naming its line (YAML keeps the last one silently)
    ("window:\n  size: 5\n  size: 4\n", ":3: key 'window.size' given twice"),
    ("mode: track\nwindow: {size: 5}\nmode: window\n", ":3: key 'mode' given twice"),
    # a setting that moved
    ("tracking: {huber_k: 2.0}\n", "key 'tracking.huber_k': is now key 'photometric.huber_k'"),
    ("loop_closure: true\n", "key 'loop_closure': is now key 'loops.enabled'"),
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
    assert vo.motion.kalman.noise.accel_sigmas == (3.0, 3.0, 1.0)
    assert vo.motion.kalman.initial_rate_sigmas == (2.0, 2.0, 0.25)
    with pytest.raises(InputError, match="key 'motion_model.kalman_initial_rate_sigmas': must be in \\[1e-6, 1000\\]"):
        config_from_dict({"motion_model": {"kalman_initial_rate_sigmas": [1, 1, 0]}})


#: The packages the settings must not load: readers, front end, motion model, window, loop closing,
#: refinement, odometry and what stands above them.
COMPONENTS = ("gtvo.datasets", "gtvo.frontend", "gtvo.motion", "gtvo.window", "gtvo.loops", "gtvo.refinement",
              "gtvo.odometry", "gtvo.io", "gtvo.pipeline", "gtvo.report", "gtvo.evaluation", "gtvo.posegraph")


@pytest.mark.slow
def test_importing_the_settings_loads_no_component():
    """``import gtvo.config`` in a fresh interpreter loads the settings core, the factors' parameters
    and nothing of the components (it loaded 84 gtvo and factors modules when the tree imported its
    sections from them; 35 now)."""
    code = ("import sys, json; import gtvo.config; "
            "print(json.dumps(sorted(m for m in sys.modules if m.split('.')[0] in ('gtvo', 'factors'))))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True,
                         cwd=Path(__file__).resolve().parent.parent)
    loaded = json.loads(out.stdout)
    components = [m for m in loaded if m.startswith(tuple(p + "." for p in COMPONENTS)) or m in COMPONENTS]
    assert components == [], f"import gtvo.config loads {len(components)} component modules: {components}"
    assert "gtvo.config.tree" in loaded and "factors.params" in loaded  # the probe sees what it imports
    assert len(loaded) <= 40, f"import gtvo.config loads {len(loaded)} gtvo / factors modules: {loaded}"


def test_every_section_imports_only_the_settings_core():
    """Each module of gtvo/config/sections imports only the core, the errors, ``factors.params`` and
    other sections (read with ``ast``, imports inside functions included)."""
    from test_layers import imports_of  # noqa: PLC0415

    root = Path(__file__).resolve().parent.parent
    allowed = ("gtvo.core", "gtvo.errors", "factors.params", "gtvo.config.sections")
    sections = sorted((root / "gtvo" / "config" / "sections").glob("*.py"))
    assert len(sections) >= 10
    wrong = {p.name: sorted(m for m in imports_of(p) if not m.startswith(allowed) and m not in ("gtvo", "gtvo.config"))
             for p in sections}
    assert {k: v for k, v in wrong.items() if v} == {}
