"""gtvo.report: the typed run report (RunReport) against the report.json a run writes, its
headline figures and reading it back; gtvo.odometry.summary, the odometry's part of it."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

import gtvo
from gtvo.config import OdometryConfig
from gtvo.datasets.synthetic import make_synthetic_sequence
from gtvo.errors import InputError
from gtvo.odometry import VisualOdometry
from gtvo.odometry.summary import OdometrySummary, summarize_odometry
from gtvo.report import HEADLINE_FIELDS, RunReport, headline, read_report
from gtvo.window.config import WindowConfig

#: Keys a report holds only in situations these runs do not make: no ground truth, an ATE whose
#: alignment is undetermined, a ROS bag, no open3d (or open3d), no point left out, the output folder,
#: wheel odometry (tests/test_odometry_wheel.py reads its ``wheel_calibration``), an IMU
#: (tests/test_odometry_imu.py reads its ``imu``).
RARE_KEYS = {"ground_truth", "ate_skipped", "unpaired_messages", "map_points_left_out_by_reason",
             "out", "wheel_calibration", "refine",  # refine: tests/test_refinement.py
             "window_worker",  # tests/test_parallel_window.py
             "imu"}


def fields(typed_dict) -> set[str]:
    return set(typed_dict.__required_keys__) | set(typed_dict.__optional_keys__)


@pytest.fixture(scope="module")
def reports(tmp_path_factory) -> dict[str, tuple[dict, dict]]:
    """A window run (with the rig calibration, the default), a track run and a loop-closure run without
    it, of 8 synthetic frames: ``name -> (what gtvo.run returned, report.json)``."""
    seq = make_synthetic_sequence(n_frames=8)
    runs = {"window": {"config": OdometryConfig(mode="window", window=WindowConfig(rig_calibration=True))},
            "track": {"config": OdometryConfig(mode="track")},
            "loops": {"config": OdometryConfig(mode="window", window=WindowConfig(rig_calibration=False)),
                      "loop_closure": True}}
    out: dict[str, tuple[dict, dict]] = {}
    for name, options in runs.items():
        folder = tmp_path_factory.mktemp(name)
        returned = gtvo.run(seq, out=folder, **options)
        out[name] = (dict(returned), json.loads((folder / "report.json").read_text()))
    return out


@pytest.mark.slow
def test_run_report_fields_are_the_keys_report_json_has(reports):
    declared = fields(RunReport)
    seen: set[str] = set()
    for name, (_, written) in reports.items():
        assert set(written) <= declared, f"{name}: report.json keys RunReport does not declare"
        assert RunReport.__required_keys__ <= set(written), f"{name}: required keys missing"
        seen |= set(written)
    assert declared - RARE_KEYS <= seen, f"declared but never written: {declared - RARE_KEYS - seen}"
    assert {k for k in seen if k.startswith("loop")} == {"loops_detected", "loops_unrefined", "loops_accepted",
                                                          "loop_closure_solver", "loop_closed_ate_rmse_m",
                                                          "loop_closed_drift_percent"}


@pytest.mark.slow
def test_the_returned_report_is_report_json_in_its_order_with_out(reports):
    for returned, written in reports.values():
        assert list(returned) == [*written, "out"]
        assert returned["frames"] == written["frames"] and returned["ate_rmse_m"] == written["ate_rmse_m"]


@pytest.mark.slow
def test_each_mode_has_its_sections(reports):
    track, window, loops = (reports[n][1] for n in ("track", "window", "loops"))
    assert "window_backend" not in track and "rig_calibration" not in track and "loops_detected" not in track
    assert track["covariances"] == "not computed (track mode: no window)"
    assert window["window_backend"] == "lm" and window["rig_calibration"] is True and "rig_offset_px" in window
    assert window["covariances"] == "written" and window["covariance_keyframes"] == window["keyframes"]
    assert loops["loop_closure_solver"] == "gtsam_gnc_lm" and "rig_offset_px" not in loops


def test_odometry_summary_is_the_reports_odometry_part_in_order():
    seq = make_synthetic_sequence(n_frames=5)
    vo = VisualOdometry(seq.camera, OdometryConfig(mode="track"))
    for i in range(len(seq)):
        vo.process(seq.frame(i))
    vo.finish()
    summary = summarize_odometry(vo, seconds=2.0, skipped=[(5, "unreadable")])
    assert set(summary) <= fields(OdometrySummary)
    assert list(summary)[:3] == ["mode", "tracker_solver", "motion_model"] and list(summary)[-1] == "covariances"
    assert summary["frames"] == 5 and summary["frames_per_second"] == 2.5
    assert summary["skipped_frames"] == [5] and summary["frame_outcomes"]["skipped"] == [
        {"index": 5, "reason": "unreadable"}]
    assert "seconds_by_stage" in summary  # the run was timed (vo.clock)
    untimed = summarize_odometry(vo)
    assert untimed["seconds"] is None and untimed["frames_per_second"] is None


def test_run_report_is_exported():
    assert gtvo.RunReport is RunReport and "RunReport" in gtvo.__all__


def test_headline_keeps_the_order_and_drops_what_is_absent_or_none():
    report = {"ate_rmse_m": 0.1, "frames": 3, "scale_ratio": None, "sequence": "s"}
    assert headline(report) == [("frames", 3), ("ate_rmse_m", 0.1)]  # type: ignore[arg-type]
    assert set(HEADLINE_FIELDS) <= fields(RunReport)


def test_read_report_round_trip_and_one_line_errors(reports, tmp_path: Path):
    path = tmp_path / "report.json"
    path.write_text(json.dumps(reports["track"][1]))
    assert read_report(path) == reports["track"][1]
    path.write_text("[1, 2]")
    with pytest.raises(InputError, match="not a JSON object"):
        read_report(path)
    with pytest.raises(InputError, match="cannot read") as err:
        read_report(tmp_path / "missing.json")
    assert "\n" not in str(err.value) and "missing.json" in str(err.value)


@pytest.mark.slow
def test_the_report_is_built_in_one_place_from_the_result_and_written_as_built(tmp_path):
    """run_report builds every key from the odometry's result (the map's counts and the timing
    included, the timing at the odometry's place in the order); the writer adds nothing."""
    from gtvo.io.outputs import write_run_outputs  # noqa: PLC0415
    from gtvo.odometry.summary import odometry_result  # noqa: PLC0415
    from gtvo.report import map_points_figures, run_metrics, run_report  # noqa: PLC0415

    seq = make_synthetic_sequence(n_frames=5)
    vo = VisualOdometry(seq.camera, OdometryConfig(mode="track"))
    for i in range(len(seq)):
        vo.process(seq.frame(i))
    vo.finish()
    odo = odometry_result(vo, seconds=1.0, name=seq.name)
    points = odo.map_points()
    timing = {"seconds_by_stage": {"tracking": 9.0}, "ms_per_frame_by_stage": {"tracking": 1800.0}}
    report = run_report(seq, odo, run_metrics(seq, odo), points=points, timing=timing)
    keys = list(report)
    assert keys[:2] == ["sequence", "source"] and keys[2:2 + len(odo.summary)] == list(odo.summary)
    assert report["seconds_by_stage"] == {"tracking": 9.0} and report["frames"] == 5
    assert {k: report[k] for k in map_points_figures(points)} == map_points_figures(points)
    assert report["ate_rmse_m"] is not None and report["config"]["mode"] == "track"
    built = []
    written = write_run_outputs(tmp_path / "out", odo.trajectory, seq, lambda: built.append(1) or report,
                                points=points)
    assert built == [1] and written == report
    assert json.loads((tmp_path / "out" / "report.json").read_text()).keys() == report.keys()
