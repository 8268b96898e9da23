"""`gtvo batch` / gtvo.batch: SPEC reading, per-log overrides, the pool and Ray runners, resume,
the summary, and the exit codes (tiny synthetic logs: 6 frames of 160x120)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

import gtvo
from gtvo import cli
from gtvo.batching import read_spec
from gtvo.batching.overrides import apply_overrides, config_identity
from gtvo.errors import InputError
from gtvo.config import FrontendConfig, OdometryConfig
from gtvo.datasets.synthetic import make_synthetic_sequence, write_sequence_kitti


def run_cli(*args):
    return subprocess.run([sys.executable, "-m", "gtvo", *map(str, args)], capture_output=True, text=True, timeout=300)


def write_stereo_bag(seq, path: Path) -> Path:
    """``seq`` as a ROS1 bag: rectified left/right images (mono8) with their CameraInfo."""
    import numpy as np

    from tests._bags import BagWriter

    K = seq.camera.left.K
    P_right = np.hstack([K, [[-K[0, 0] * seq.camera.baseline], [0.0], [0.0]]])
    with BagWriter(path) as bag:
        for i in range(len(seq)):
            ns = 1_000_000_000 + i * 100_000_000
            if i == 0:
                for side, P in (("left", np.hstack([K, np.zeros((3, 1))])), ("right", P_right)):
                    bag.camera_info(f"/cam/{side}/camera_info", ns, seq.camera.left.width, seq.camera.left.height,
                                    K, P)
            for side, image in (("left", seq.left(i)), ("right", seq.right(i))):
                bag.image(f"/cam/{side}/image_rect", ns, np.clip(np.rint(image), 0, 255).astype(np.uint8), "mono8")
    return path


@pytest.fixture(scope="module")
def logs(tmp_path_factory) -> Path:
    """A fleet folder: two tiny logs (different seeds), a ROS bag of a third, a broken (empty)
    log folder and a note."""
    root = tmp_path_factory.mktemp("fleet") / "logs"
    for seed in (1, 2):
        write_sequence_kitti(make_synthetic_sequence(n_frames=6, width=160, height=120, seed=seed), root / f"seq{seed}")
    write_stereo_bag(make_synthetic_sequence(n_frames=6, width=160, height=120, seed=3), root / "drive.bag")
    (root / "broken").mkdir()
    (root / "notes.txt").write_text("week 12\n")
    (root / ".hidden").mkdir()
    return root


@pytest.fixture(scope="module")
def pool_run(logs, tmp_path_factory):
    """The fleet run once on the local process pool (2 workers) through the Python API."""
    out = tmp_path_factory.mktemp("pool") / "out"
    before = os.environ.get("OPENBLAS_NUM_THREADS")
    os.environ["OPENBLAS_NUM_THREADS"] = "2"  # the workers must still run BLAS single-threaded
    try:
        return gtvo.batch(logs, out, jobs=2, progress=False)
    finally:
        if before is None:
            del os.environ["OPENBLAS_NUM_THREADS"]
        else:
            os.environ["OPENBLAS_NUM_THREADS"] = before


# ---------------------------------------------------------------------------------------------
# configuration overrides and identity
# ---------------------------------------------------------------------------------------------

def test_overrides_reach_nested_settings():
    base = OdometryConfig()
    cfg = apply_overrides(base, {"mode": "track", "frontend": {"points_per_keyframe": 400},
                                 "window": {"size": 5}, "tracking": {"max_iterations": 7}})
    assert cfg.mode == "track" and cfg.frontend.points_per_keyframe == 400
    assert cfg.window.size == 5 and cfg.tracking.max_iterations == 7
    assert cfg.window.lambda_stereo == base.window.lambda_stereo  # untouched settings keep their values
    assert apply_overrides(base, {}) is base


@pytest.mark.parametrize("overrides, needle", [
    ({"window": {"sise": 5}}, "'window.sise'"),
    ({"window": {"size": "5"}}, "'window.size': must be an integer"),
    ({"mode": "fast"}, "'mode': must be one of"),
    ({"window": {"size": 1}}, "'window.size': must be in [2, 100]"),
])
def test_bad_overrides_name_the_key_and_the_file(overrides, needle):
    with pytest.raises(InputError) as e:
        apply_overrides(OdometryConfig(), overrides, where="fleet.yaml, log 'a'")
    assert needle in str(e.value) and str(e.value).startswith("fleet.yaml, log 'a': ")


def test_config_identity_follows_the_settings():
    a = config_identity(OdometryConfig())
    assert a == config_identity(apply_overrides(OdometryConfig(), {"frontend": {"points_per_keyframe": 300}}))
    assert a != config_identity(apply_overrides(OdometryConfig(), {"frontend": {"points_per_keyframe": 400}}))
    assert a != config_identity(apply_overrides(OdometryConfig(), {"window": {"size": 5}}))
    assert len(a) == 12 and int(a, 16) >= 0


# ---------------------------------------------------------------------------------------------
# SPEC
# ---------------------------------------------------------------------------------------------

@pytest.mark.slow
def test_spec_folder_takes_every_detected_log_and_flags_broken_folders(logs):
    specs = read_spec(logs)
    # notes.txt and .hidden are not logs; a bag is one (through gtvo.datasets.detect_format)
    assert [s.name for s in specs] == ["broken", "drive", "seq1", "seq2"]
    assert [s.format for s in specs[1:]] == ["bag", "kitti", "kitti"] and specs[1].problem is None
    assert specs[0].problem is not None and "unknown dataset layout" in specs[0].problem
    for single in ("seq1", "drive.bag"):
        with pytest.raises(InputError, match="itself one log"):
            read_spec(logs / single)
    assert [s.name for s in read_spec(logs, exclude=(logs / "broken",))] == ["drive", "seq1", "seq2"]


@pytest.mark.slow
def test_spec_yaml_entries(logs, tmp_path):
    spec = tmp_path / "fleet.yaml"
    spec.write_text(f"- {logs / 'seq1'}\n"
                    "- path: ../" + os.path.relpath(logs / "seq2", tmp_path.parent) + "\n"
                    "  name: second\n  format: kitti\n  max_frames: 3\n  camera: [1, 2, 3, 4]\n"
                    "  config: {frontend: {points_per_keyframe: 400}, window: {size: 4}}\n")
    a, b = read_spec(spec)
    assert (a.name, a.path, a.format, a.config) == ("seq1", (logs / "seq1").resolve(), "auto", {})
    assert (b.name, b.path, b.format) == ("second", (logs / "seq2").resolve(), "kitti")
    spec.write_text("- {path: a, name: drive 3 (rain)}\n")  # any single folder name
    assert read_spec(spec)[0].name == "drive 3 (rain)"
    assert b.options == {"max_frames": 3, "camera": (1.0, 2.0, 3.0, 4.0)}
    assert b.config == {"frontend": {"points_per_keyframe": 400}, "window": {"size": 4}}


@pytest.mark.parametrize("text, needle", [
    ("- a\n- a\n", "two logs are named 'a'"),
    ("- path: a\n  nmae: x\n", "log 1: unknown key 'nmae'"),
    ("- name: x\n", "log 1: 'path' (the log) is required"),
    ("path: a\n", "must be a list of logs"),
    ("- path: a\n  max_frames: 0\n", "'max_frames' must be an integer >= 1"),
    ("- path: a\n  name: ../up\n", "log name '../up' cannot be"),
    ("- path: a\n  name: .hidden\n", "log name '.hidden' cannot be"),
    ("- path: a\n  name: summary.json\n", "log name 'summary.json' cannot be"),
    ("- path: a\n  config: [1]\n", "'config' must be a mapping"),
    ("- path: a\n  format: kiti\n", "unknown 'format' 'kiti' (known: auto, kitti"),
    ("- [a\n", "not valid YAML"),
    ("[]\n", "holds no logs"),
])
def test_bad_spec_yaml_is_one_line_naming_the_file(tmp_path, text, needle):
    spec = tmp_path / "fleet.yaml"
    spec.write_text(text)
    with pytest.raises(InputError) as e:
        read_spec(spec)
    assert needle in str(e.value) and "fleet.yaml" in str(e.value) and "\n" not in str(e.value)


# ---------------------------------------------------------------------------------------------
# runs (process pool)
# ---------------------------------------------------------------------------------------------

@pytest.mark.slow
def test_pool_batch_runs_each_log_and_reports_the_broken_one(pool_run, logs):
    assert callable(gtvo.batch)  # the function, even though gtvo.batching is imported
    res = pool_run
    assert res.failed == ["broken"] and not res.ok and res.resumed == []
    summary = json.loads(res.summary["json"].read_text())
    rows = {r["name"]: r for r in summary["logs"]}
    assert list(rows) == ["broken", "drive", "seq1", "seq2"] and summary["logs_failed"] == 1
    bag = rows["drive"]  # a ROS bag (no ground truth): it runs, and its metrics stay empty
    assert bag["status"] == "done" and bag["format"] == "bag" and bag["frames"] == 6
    assert bag["ate_rmse_m"] is None and bag["sim3_ate_rmse_m"] is None
    assert (res.out / "drive" / "trajectory.tum").is_file()
    assert rows["broken"]["status"] == "failed" and "unknown dataset layout" in rows["broken"]["error"]
    for name in ("seq1", "seq2"):
        row = rows[name]
        report = json.loads((res.out / name / "report.json").read_text())
        assert row["status"] == "done" and row["frames"] == report["frames"] == 6
        assert row["ate_rmse_m"] == report["ate_rmse_m"] and row["ate_rmse_m"] < 0.02
        assert 0 < row["sim3_ate_rmse_m"] <= row["ate_rmse_m"] + 1e-12  # Sim(3) has one more freedom
        assert row["kitti_translation_percent"] == report["kitti_translation_percent"]
        assert row["config_id"] == config_identity(OdometryConfig())
        for f in ("trajectory.tum", "trajectory.png", "batch.json"):
            assert (res.out / name / f).is_file()
        assert json.loads((res.out / name / "batch.json").read_text())["blas_threads"] == 1
    assert rows["seq1"]["ate_rmse_m"] != rows["seq2"]["ate_rmse_m"]  # two different logs
    md = res.summary["md"].read_text()
    assert "| seq1 | done | 6 |" in md and "## Failed logs" in md and "`broken`" in md
    assert res.summary["png"].stat().st_size > 1000
    assert not (res.out / "broken").exists()  # a failed log leaves no empty folder
    assert not [p for p in res.out.iterdir() if p.name.startswith(".")]  # no temporary files


@pytest.mark.slow
def test_resume_skips_complete_logs_and_reruns_the_rest(pool_run, logs, tmp_path, capsys):
    import shutil

    out = tmp_path / "out"
    shutil.copytree(pool_run.out, out)
    (out / "seq2" / "batch.json").unlink()  # as if the batch was interrupted before seq2 finished
    before = (out / "seq1" / "trajectory.tum").stat().st_mtime_ns
    res = gtvo.batch(logs, out, jobs=1, resume=True, progress=True)
    assert res.resumed == ["drive", "seq1"] and res.failed == ["broken"]
    bar = capsys.readouterr().err
    assert "gtvo batch" in bar and "4/4" in bar and "log" in bar  # the progress bar over the logs
    assert (out / "seq1" / "trajectory.tum").stat().st_mtime_ns == before
    assert (out / "seq2" / "batch.json").is_file()
    rows = {r["name"]: r for r in res.rows}
    assert rows["seq1"]["resumed"] and not rows["seq2"]["resumed"] and rows["seq1"]["frames"] == 6
    assert (out / "seq2" / "trajectory.tum").read_bytes() == (pool_run.out / "seq2" / "trajectory.tum").read_bytes()
    # other settings are another job: nothing is resumed
    res = gtvo.batch(logs, out, jobs=1, resume=True, progress=False, max_frames=3,
                     config=OdometryConfig(frontend=FrontendConfig(points_per_keyframe=200)))
    assert res.resumed == [] and {r["name"]: r["frames"] for r in res.rows if r["status"] == "done"} == \
        {"drive": 3, "seq1": 3, "seq2": 3}


@pytest.mark.slow
def test_cli_yaml_with_overrides_and_a_failing_log_exits_1(logs, tmp_path):
    (tmp_path / "empty").mkdir()
    spec = tmp_path / "study.yaml"
    spec.write_text(f"- {{path: {logs / 'seq1'}, name: base}}\n"
                    f"- {{path: {logs / 'seq1'}, name: fewer_points,\n"
                    "   config: {frontend: {points_per_keyframe: 150}, window: {size: 3}}}\n"
                    "- {path: empty, name: bad}\n")
    out = tmp_path / "out"
    r = run_cli("batch", spec, "--out", out, "--jobs", "2", "--max-frames", "4", "--no-progress")
    assert r.returncode == 1, r.stderr
    assert "2 of 3 logs done" in r.stdout and "failed bad:" in r.stdout
    assert "log/s" not in r.stderr and "s/log" not in r.stderr  # --no-progress
    rows = {row["name"]: row for row in json.loads((out / "summary.json").read_text())["logs"]}
    assert rows["base"]["frames"] == rows["fewer_points"]["frames"] == 4
    assert rows["base"]["config_id"] != rows["fewer_points"]["config_id"]
    assert rows["fewer_points"]["config_overrides"] == {"frontend": {"points_per_keyframe": 150},
                                                        "window": {"size": 3}}
    assert rows["bad"]["status"] == "failed" and "empty" in rows["bad"]["error"]
    # each log ran exactly as `gtvo run` runs it
    single = tmp_path / "single"
    r = run_cli("run", logs / "seq1", "--out", single, "--max-frames", "4", "--no-progress")
    assert r.returncode == 0, r.stderr
    assert (single / "trajectory.tum").read_bytes() == (out / "base" / "trajectory.tum").read_bytes()
    assert (single / "trajectory.tum").read_bytes() != (out / "fewer_points" / "trajectory.tum").read_bytes()


@pytest.mark.parametrize("make_spec, needle", [
    (lambda d: d / "missing", "SPEC not found"),
    (lambda d: _write(d / "s.yaml", "- {path: x, config: {window: {sise: 3}}}\n"), "'window.sise'"),
    (lambda d: _write(d / "s.yaml", "- {path: x, config: {mode: fast}}\n"), "'mode': must be one of"),
])
def test_bad_spec_exit_2_one_line_and_no_output_folder(tmp_path, capsys, make_spec, needle):
    spec = make_spec(tmp_path)
    out = tmp_path / "new" / "out"
    assert cli.main(["batch", str(spec), "--out", str(out), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert needle in err and err.count("\n") == 1 and err.startswith("gtvo batch: error:")
    if spec.suffix == ".yaml":
        assert "s.yaml" in err
    assert not (tmp_path / "new").exists()


def test_bad_jobs_exit_2(tmp_path, capsys):
    assert cli.main(["batch", str(tmp_path), "--out", str(tmp_path / "o"), "--jobs", "0"]) == 2
    assert "--jobs must be >= 1" in capsys.readouterr().err


def test_ray_missing_is_one_line_naming_the_extra(tmp_path, capsys, monkeypatch):
    monkeypatch.setitem(sys.modules, "ray", None)  # import ray fails as if it were not installed
    assert cli.main(["batch", str(tmp_path), "--out", str(tmp_path / "o"), "--ray", "local"]) == 2
    err = capsys.readouterr().err
    assert 'pip install "gtvo[ray]"' in err and err.count("\n") == 1
    assert not (tmp_path / "o").exists()


@pytest.mark.slow
def test_a_log_that_kills_its_worker_fails_alone():
    from gtvo.batching.runners import run_in_pool
    from tests._batch_tasks import crash_or_pass

    jobs = [{"name": f"log{i}", "crash": i == 2} for i in range(5)]
    calls: list[tuple[int, dict]] = []
    run_in_pool(jobs, 2, lambda i, r: calls.append((i, r)), task=crash_or_pass)
    assert sorted(i for i, _ in calls) == [0, 1, 2, 3, 4]  # every log reported exactly once
    results = dict(calls)
    assert results[2]["status"] == "failed" and "worker process died" in results[2]["error"]
    assert all(results[i]["status"] == "done" for i in (0, 1, 3, 4))


# ---------------------------------------------------------------------------------------------
# Ray
# ---------------------------------------------------------------------------------------------

@pytest.mark.slow
def test_ray_address_where_nothing_answers_exit_2_at_once(logs, tmp_path, capsys):
    pytest.importorskip("ray", reason="Ray is not installed (pip install 'gtvo[ray]')")
    import socket

    with socket.socket() as s:  # a port that was free a moment ago: nothing listens there
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    assert cli.main(["batch", str(logs), "--out", str(tmp_path / "o"), "--ray", f"127.0.0.1:{port}"]) == 2
    err = capsys.readouterr().err
    assert f"--ray 127.0.0.1:{port}: nothing answers" in err and err.count("\n") == 1
    assert not (tmp_path / "o").exists()


@pytest.mark.slow
def test_ray_local_equals_the_pool_to_the_bit(pool_run, logs, tmp_path):
    ray = pytest.importorskip("ray", reason="Ray is not installed (pip install 'gtvo[ray]')")
    assert not ray.is_initialized()
    res = gtvo.batch(logs, tmp_path / "out", jobs=2, ray="local", progress=False)
    assert not ray.is_initialized()  # the local Ray it started is shut down
    assert res.failed == ["broken"]
    summary = json.loads(res.summary["json"].read_text())
    assert summary["runner"] == "ray (local)"
    for name in ("drive", "seq1", "seq2"):
        assert (res.out / name / "trajectory.tum").read_bytes() == \
            (pool_run.out / name / "trajectory.tum").read_bytes(), name
        assert json.loads((res.out / name / "batch.json").read_text())["blas_threads"] == 1
        assert (json.loads((res.out / name / "report.json").read_text()).get("ate_rmse_m")
                == json.loads((pool_run.out / name / "report.json").read_text()).get("ate_rmse_m"))


def _write(path: Path, text: str) -> Path:
    path.write_text(text)
    return path


def test_a_logs_row_takes_the_sim3_ate_from_its_report_not_from_trajectory_tum(tmp_path, monkeypatch):
    """The record and the summary row hold the report's ``ate_sim3_rmse_m``; nothing re-reads
    ``trajectory.tum`` (this run writes none) to recompute it."""
    import gtvo.datasets
    import gtvo.pipeline
    from gtvo.batching.runners import run_log
    from gtvo.batching.spec import LogSpec
    from gtvo.batching.summary import summary_row

    monkeypatch.setattr(gtvo.datasets, "open_sequence", lambda *a, **k: make_synthetic_sequence(n_frames=3))
    monkeypatch.setattr(gtvo.pipeline, "run", lambda *a, **k: {"ate_sim3_rmse_m": 0.123, "seconds": 1.5})
    job = {"name": "fake", "path": str(tmp_path), "format": "kitti", "out": str(tmp_path / "out"),
           "config": OdometryConfig(), "options": {}, "key": {"config_id": "x"}}
    (tmp_path / "out").mkdir()
    result = run_log(job)
    assert result["status"] == "done", result
    assert result["record"]["sim3_ate_rmse_m"] == 0.123 and result["record"]["run_seconds"] == 1.5
    log = LogSpec(name="fake", path=tmp_path, format="kitti")
    row = summary_row(log, "x", tmp_path / "out", {"status": "done", "record": {}},
                      {"ate_sim3_rmse_m": 0.456, "ate_rmse_m": 0.5}, resumed=False)  # type: ignore[arg-type]
    assert row["sim3_ate_rmse_m"] == 0.456 and row["ate_rmse_m"] == 0.5


# ---------------------------------------------------------------------------------------------
# hostile paths: nothing written into a log, link loops reported, one batch per output folder
# ---------------------------------------------------------------------------------------------

@pytest.fixture()
def fleet_copy(logs, tmp_path) -> Path:
    """Two tiny logs in a SPEC folder of this test's own."""
    import shutil

    root = tmp_path / "spec"
    for name in ("seq1", "seq2"):
        shutil.copytree(logs / name, root / name)
    return root


def _listing(folder: Path) -> list[str]:
    return sorted(str(p.relative_to(folder)) for p in folder.rglob("*"))


def test_out_that_is_a_log_or_inside_one_is_refused_whatever_the_spelling(fleet_copy, tmp_path, capsys):
    """`gtvo batch SPEC --out SPEC/seq1` (once: exit 0, seq1 dropped and the summary and the other
    logs' outputs written into seq1's data folder), through a link, '..' or below: exit 2, one line,
    nothing written anywhere."""
    (tmp_path / "alias").symlink_to(fleet_copy / "seq1")
    yaml = _write(tmp_path / "s.yaml", f"- {fleet_copy / 'seq1'}\n- {fleet_copy / 'seq2'}\n")
    before = _listing(tmp_path)
    for spec, out in ((fleet_copy, fleet_copy / "seq1"), (fleet_copy, tmp_path / "alias"),
                      (fleet_copy, fleet_copy / "seq2" / ".." / "seq1"), (fleet_copy, fleet_copy / "seq1" / "out"),
                      (fleet_copy, tmp_path / "alias" / "image_0" / "new"), (yaml, fleet_copy / "seq2"),
                      (yaml, tmp_path / "alias" / "deeper" / "out")):
        assert cli.main(["batch", str(spec), "--out", str(out), "--no-progress"]) == 2, out
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and "output folder is" in err and "log" in err, err
    assert _listing(tmp_path) == before


def test_out_that_is_a_link_loop_is_one_line(fleet_copy, tmp_path, capsys):
    loop = tmp_path / "loop"
    loop.symlink_to("loop")
    for out in (loop, loop / "inside"):
        assert cli.main(["batch", str(fleet_copy), "--out", str(out), "--no-progress"]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and "symbolic link loop" in err and "Traceback" not in err, err


def test_one_log_given_twice_with_the_same_settings_is_refused(fleet_copy, tmp_path, capsys):
    (fleet_copy / "again").symlink_to(fleet_copy / "seq1")
    assert cli.main(["batch", str(fleet_copy), "--out", str(tmp_path / "out"), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "'again' and 'seq1' are the same log" in err, err
    assert not (tmp_path / "out").exists()
    # the same log under other settings is a study, not a repeat
    (fleet_copy / "again").unlink()
    logs = read_spec(_write(tmp_path / "s.yaml", f"- {{path: {fleet_copy / 'seq1'}}}\n"
                                                  f"- {{path: {fleet_copy / 'seq1'}, name: b, max_frames: 3}}\n"))
    assert [lg.name for lg in logs] == ["seq1", "b"]


def test_a_second_batch_into_a_held_output_folder_is_refused(fleet_copy, tmp_path, capsys):
    from gtvo.core.atomic import output_lock

    out = tmp_path / "out"
    with output_lock(out):
        assert cli.main(["batch", str(fleet_copy), "--out", str(out), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "another gtvo process" in err, err


def test_broken_links_among_the_logs_are_failed_rows_with_their_reason(fleet_copy, tmp_path):
    """A SPEC folder entry that is a link loop or a broken link (once: a RuntimeError ending the
    whole batch, or the entry silently dropped) is a log that fails with its reason; the others go on."""
    (fleet_copy / "loopy").symlink_to("loopy")
    (fleet_copy / "gone").symlink_to(tmp_path / "nowhere")
    logs = {lg.name: lg for lg in read_spec(fleet_copy)}
    assert logs["loopy"].problem.endswith("loopy is a symbolic link loop")
    assert "gone is a broken symbolic link" in logs["gone"].problem
    assert logs["seq1"].problem is None
    yaml = _write(tmp_path / "s.yaml", f"- {fleet_copy / 'loopy'}\n- {fleet_copy / 'seq1'}\n"
                                        f"- {{path: {fleet_copy / 'seq2'}, ground_truth: {fleet_copy / 'loopy'}}}\n")
    assert [lg.problem is None for lg in read_spec(yaml)] == [False, True, True]  # (seq2 fails when it runs)


@pytest.mark.slow
def test_a_batch_with_broken_links_and_a_link_loop_image_goes_on(fleet_copy, tmp_path):
    (fleet_copy / "loopy").symlink_to("loopy")
    image = fleet_copy / "seq2" / "image_0" / "000002.png"
    image.unlink()
    image.symlink_to(image.name)  # a frame that is a link loop: skipped, the log runs
    out = tmp_path / "out"
    r = run_cli("batch", fleet_copy, "--out", out, "--jobs", "2", "--no-progress")
    assert r.returncode == 1 and "Traceback" not in r.stderr, r.stderr
    assert "2 of 3 logs done, 1 failed" in r.stdout and "failed loopy:" in r.stdout, r.stdout
    rows = {row["name"]: row for row in json.loads((out / "summary.json").read_text())["logs"]}
    assert rows["loopy"]["status"] == "failed" and "symbolic link loop" in rows["loopy"]["error"]
    assert rows["seq1"]["status"] == rows["seq2"]["status"] == "done"
    assert sorted(p.name for p in out.iterdir()) == ["seq1", "seq2", "summary.json", "summary.md", "summary.png"]


def test_an_interrupted_batch_leaves_a_summary_of_what_finished_marked_partial(fleet_copy, tmp_path, monkeypatch):
    """Ctrl-C after the first log: the earlier batch's summary is not left beside this batch's
    outputs; the summary says what finished, which logs did not run, and that it is partial."""
    import gtvo.batching as batching
    from gtvo.batching.runners import failure

    out = tmp_path / "out"
    out.mkdir()
    (out / "summary.json").write_text(json.dumps({"logs": [{"name": "earlier"}]}))

    def interrupted(jobs, workers, on_done):
        on_done(0, failure(InputError("a bad frame")))
        raise KeyboardInterrupt

    monkeypatch.setattr(batching, "run_in_pool", interrupted)
    with pytest.raises(KeyboardInterrupt):
        batching.batch(fleet_copy, out, jobs=1, progress=False)
    summary = json.loads((out / "summary.json").read_text())
    assert summary["partial"] is True and summary["logs_not_run"] == 1 and summary["logs_failed"] == 1
    assert [(r["name"], r["status"]) for r in summary["logs"]] == [("seq1", "failed"), ("seq2", "not run")]
    assert "Partial: the batch was interrupted; 1 logs were not run." in (out / "summary.md").read_text()
    assert not [p for p in out.parent.iterdir() if p.name.startswith(".")]  # no lock, no staging left


def _bind(source: Path, target: Path, read_only: bool = False) -> bool:
    """Bind-mount ``source`` on ``target`` (False: not allowed here)."""
    target.mkdir(parents=True, exist_ok=True)
    if subprocess.run(["mount", "--bind", str(source), str(target)], capture_output=True).returncode != 0:
        return False
    if read_only and subprocess.run(["mount", "-o", "remount,ro,bind", str(target)],
                                    capture_output=True).returncode != 0:
        subprocess.run(["umount", str(target)], check=True)
        return False
    return True


def test_out_through_a_bind_mount_of_the_logs_and_a_read_only_out_are_refused(fleet_copy, tmp_path, capsys):
    """A bind mount shows the SPEC folder under a path no string comparison relates to it; a
    read-only mount refuses writes even to root. Both: one line, exit 2, nothing written."""
    mount, ro = tmp_path / "mnt", tmp_path / "ro"
    if not _bind(fleet_copy, mount):
        pytest.skip("cannot bind-mount here")
    try:
        before = _listing(fleet_copy)
        for out in (mount / "seq1", mount / "seq2" / "results"):
            assert cli.main(["batch", str(fleet_copy), "--out", str(out), "--no-progress"]) == 2, out
            err = capsys.readouterr().err
            assert err.count("\n") == 1 and "log" in err, err
        assert cli.main(["run", str(fleet_copy / "seq1"), "--out", str(mount / "seq1" / "res"), "--no-progress"]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and "inside the input folder" in err, err
        assert _listing(fleet_copy) == before
    finally:
        subprocess.run(["umount", str(mount)], check=True)
    (tmp_path / "empty").mkdir()
    if not _bind(tmp_path / "empty", ro, read_only=True):
        pytest.skip("cannot mount read-only here")
    try:
        for out in (ro, ro / "new"):
            assert cli.main(["batch", str(fleet_copy), "--out", str(out), "--no-progress"]) == 2
            err = capsys.readouterr().err
            assert err.count("\n") == 1 and ("not writable" in err or "Read-only" in err), err
    finally:
        subprocess.run(["umount", str(ro)], check=True)


def test_a_killed_batchs_leftovers_are_removed_by_the_next_batch(fleet_copy, tmp_path, monkeypatch):
    """A batch killed (SIGTERM, SIGKILL) leaves its workers' staging folders, a temporary batch.json
    and lock files in its --out; the next batch into it removes them, whether its logs run again
    or not, and leaves what is not gtvo's alone."""
    import tempfile

    import gtvo.batching as batching
    from gtvo.batching.runners import failure

    out = tmp_path / "out"
    (out / "seq1").mkdir(parents=True)
    leftovers = [Path(tempfile.mkdtemp(prefix=".seq1.", dir=out)), Path(tempfile.mkdtemp(prefix=".seq2.", dir=out)),
                 Path(tempfile.mkstemp(prefix=".batch.json.", suffix=".json", dir=out / "seq1")[1]),
                 out / ".seq2.lock", Path(tempfile.mkstemp(prefix=".summary.md.", suffix=".md", dir=out)[1])]
    leftovers[3].write_text("4242\n")
    mine = out / ".my-notes"
    mine.write_text("keep\n")

    def nothing_runs(jobs, workers, on_done):
        for k in range(len(jobs)):
            on_done(k, failure(InputError("not run in this test")))

    monkeypatch.setattr(batching, "run_in_pool", nothing_runs)
    batching.batch(fleet_copy, out, jobs=1, progress=False)
    assert [p for p in leftovers if p.exists()] == [] and mine.read_text() == "keep\n"
