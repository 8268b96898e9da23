"""gtvo/io/log_settings.py: a log folder's wheel.yaml read like its calibration (without --config)."""

from __future__ import annotations

import json

import pytest

from gtvo import cli
from gtvo.config import OdometryConfig, config_from_dict
from gtvo.errors import InputError
from gtvo.io.log_settings import log_wheel_settings

WHEEL_YAML = ("wheel:\n  model: linear\n  nominal_baseline: 0.61\n"
              "  base_to_camera: [0.3, -0.1, 0.8, -0.5, 0.5, -0.5, 0.5]\n")


def test_a_logs_wheel_yaml_is_read_and_explicit_settings_win(tmp_path):
    (tmp_path / "wheel.yaml").write_text(WHEEL_YAML)
    config, read = log_wheel_settings(tmp_path, OdometryConfig())
    assert read == tmp_path / "wheel.yaml"
    assert config.wheel.model == "linear" and config.wheel.nominal_baseline == 0.61
    assert tuple(config.wheel.base_to_camera)[:3] == (0.3, -0.1, 0.8)
    mine = config_from_dict({"wheel": {"nominal_baseline": 0.7}, "window": {"size": 5}}, base=OdometryConfig())
    config, _ = log_wheel_settings(tmp_path, mine)
    assert config.wheel.nominal_baseline == 0.7 and config.wheel.model == "linear" and config.window.size == 5
    assert log_wheel_settings(tmp_path / "absent", mine) == (mine, None)


@pytest.mark.parametrize("text, needle", [("wheel:\n  modle: linear\n", "modle"),
                                          ("mode: track\nwheel:\n  model: linear\n", "holds only the wheel: section"),
                                          ("wheel: [1, 2\n", "wheel.yaml")])
def test_a_bad_logs_wheel_yaml_names_the_file_and_the_key(tmp_path, text, needle):
    (tmp_path / "wheel.yaml").write_text(text)
    with pytest.raises(InputError, match=needle) as info:
        log_wheel_settings(tmp_path, OdometryConfig())
    assert "wheel.yaml" in str(info.value) and "\n" not in str(info.value)


@pytest.mark.slow
def test_gtvo_run_reads_the_robots_wheel_yaml_without_config_and_says_so(tmp_path, capsys):
    """A synthetic robot's log with its wheel.yaml: `gtvo run LOG` (no --config) runs with the
    log's wheel settings (before: the defaults, a track-width scale of 1.011 against a true 1.05,
    no word) and says on the console which file it read."""
    robot = tmp_path / "robot"
    assert cli.main(["synthetic", "--out", str(robot), "--motion", "ground", "--frames", "12", "--wheel", "arcs",
                     "--wheel-calibration", "1.02,0.98,1.05", "--no-progress"]) == 0
    capsys.readouterr()
    assert cli.main(["run", str(robot), "--out", str(tmp_path / "out"), "--no-progress"]) == 0
    out = capsys.readouterr().out  # on stdout: stderr stays one line when the run then fails
    assert f"wheel settings from the log's {robot / 'wheel.yaml'}" in out, out
    report = json.loads((tmp_path / "out" / "report.json").read_text())
    expected, _ = log_wheel_settings(robot, OdometryConfig())
    from gtvo.config import config_to_dict

    assert report["config"]["wheel"] == config_to_dict(expected)["wheel"]
    assert report["config"]["wheel"] != config_to_dict(OdometryConfig())["wheel"]
