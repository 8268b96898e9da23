"""Ctrl-C ends a batch: `gtvo batch` sent SIGINT (to its process group, as a terminal's Ctrl-C, or
to the main process only) exits 130 with one line, its pool workers end with it (none runs on and
writes after the command has exited), no staging folder is left, and `--resume` finishes the
batch. Real processes and signals."""

from __future__ import annotations

import json
import os
import random
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

from gtvo import cli
from gtvo.datasets.synthetic import make_synthetic_sequence, write_sequence_kitti

ROOT = Path(__file__).resolve().parents[1]


def live_processes_in_group(pgid: int) -> list[str]:
    """The processes of process group ``pgid`` that are still running (zombies waiting for a
    parent to reap them are not), as ``"pid command"``."""
    found = []
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            stat = (entry / "stat").read_text()
            cmdline = (entry / "cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
        except OSError:
            continue
        fields = stat[stat.rindex(")") + 2:].split()  # state ppid pgrp ...
        if int(fields[2]) == pgid and fields[0] != "Z":
            found.append(f"{entry.name} {cmdline}")
    return found


def hidden_entries(folder: Path) -> list[Path]:
    """Hidden entries (staging folders, temporary files) in ``folder`` and its sub-folders, but
    the marker of a run's output folder."""
    return sorted(p for p in folder.rglob(".*") if p.name != ".gtvo-output")


def end_group(pgid: int, grace_s: float = 10.0) -> list[str]:
    """What still runs in process group ``pgid`` after ``grace_s`` (multiprocessing's resource
    tracker ends on its own once the command's pipes to it close: give it the time), SIGKILLed so
    that a failed test leaves nothing running."""
    deadline = time.monotonic() + grace_s
    while live_processes_in_group(pgid) and time.monotonic() < deadline:
        time.sleep(0.1)
    survivors = live_processes_in_group(pgid)
    for pid in (int(s.split()[0]) for s in survivors):
        try:
            os.kill(pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
    return survivors


def snapshot(folder: Path) -> dict[str, int]:
    return {str(p.relative_to(folder)): p.stat().st_mtime_ns for p in folder.rglob("*")}


@pytest.fixture(scope="module")
def fleet(tmp_path_factory) -> Path:
    """Three tiny logs (6 frames of 160x120)."""
    root = tmp_path_factory.mktemp("fleet") / "logs"
    for seed in (1, 2, 3):
        write_sequence_kitti(make_synthetic_sequence(n_frames=6, width=160, height=120, seed=seed), root / f"log{seed}")
    return root


def start_batch(fleet: Path, out: Path) -> subprocess.Popen:
    """`gtvo batch` in a session of its own (a process group, as a shell job)."""
    return subprocess.Popen([sys.executable, "-m", "gtvo", "batch", str(fleet), "--out", str(out), "--jobs", "1",
                             "--no-progress"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True,
                            # a shell's background job starts with SIGINT ignored: the child would inherit it
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))


@pytest.mark.slow
def test_sigint_to_the_group_or_the_main_process_ends_the_workers_too(fleet, tmp_path):
    t0 = time.perf_counter()
    r = subprocess.run([sys.executable, "-m", "gtvo", "--version"], capture_output=True, timeout=120)
    startup = time.perf_counter() - t0
    full = tmp_path / "full"
    t0 = time.perf_counter()
    proc = start_batch(fleet, full)
    _, err = proc.communicate(timeout=600)
    assert proc.returncode == 0, err
    seconds = time.perf_counter() - t0
    # the moments: after gtvo's start-up, spread over the batch as measured just now (its workers
    # start, run the logs one after the other and write them)
    rng = random.Random(31)
    outcomes = []
    for trial in range(4):
        out = tmp_path / f"t{trial}"
        proc = start_batch(fleet, out)
        time.sleep(rng.uniform(1.5 * startup, 0.9 * seconds))
        if trial % 2 == 0:
            os.killpg(proc.pid, signal.SIGINT)  # Ctrl-C in a terminal: the whole group
        else:
            proc.send_signal(signal.SIGINT)  # the main process only (kill -INT PID)
        try:
            _, err = proc.communicate(timeout=60)  # a worker left running would hold the pipes open
        except subprocess.TimeoutExpired:
            pytest.fail(f"trial {trial}: the batch did not end: {end_group(proc.pid, 0.0)}")
        outcomes.append(proc.returncode)
        assert proc.returncode in (0, 130), (trial, err)
        assert end_group(proc.pid) == [], trial
        if proc.returncode == 130:
            assert err.strip().splitlines() == ["gtvo batch: interrupted"], (trial, err)
        if out.exists():
            before = snapshot(out)
            time.sleep(2.0)
            assert snapshot(out) == before, f"trial {trial}: the folder changed after the batch exited"
            assert hidden_entries(out) == [], trial
        r = subprocess.run([sys.executable, "-m", "gtvo", "batch", str(fleet), "--out", str(out), "--jobs", "1",
                            "--no-progress", "--resume"], capture_output=True, text=True, timeout=600)
        assert r.returncode == 0 and "3 of 3 logs done" in r.stdout, (trial, r.stdout, r.stderr)
        for log in ("log1", "log2", "log3"):
            assert (out / log / "trajectory.tum").read_bytes() == (full / log / "trajectory.tum").read_bytes()
    assert 130 in outcomes


_STALLED_BATCH = textwrap.dedent("""
    import json, sys
    sys.path.insert(0, {root!r})
    from gtvo.batching.runners import run_in_pool
    from tests._batch_tasks import stall_in_staging
    try:
        run_in_pool(json.loads({jobs!r}), 2, lambda i, r: None, task=stall_in_staging)
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        sys.exit(130)
""")


@pytest.mark.parametrize("signalled", ["group", "main"])
def test_an_interrupt_while_workers_write_leaves_no_staging_and_the_earlier_set(tmp_path, signalled):
    """Two workers stopped inside their output swap: one mid-write (a staging folder and a
    temporary batch.json beside an earlier set), one between the two renames (its earlier set
    moved aside). After the interrupt: the earlier sets in place, nothing hidden left."""
    from gtvo.core.atomic import DIR_MARKER

    out = tmp_path / "out"
    for name in ("staged", "half"):
        (out / name).mkdir(parents=True)
        (out / name / DIR_MARKER).write_text("written by gtvo run\n")
        (out / name / "report.json").write_text(json.dumps({"earlier": name}))
    jobs = [{"name": name, "out": str(out / name), "ready": str(tmp_path / f"{name}.ready"),
             "half_swapped": name == "half"} for name in ("staged", "half")]
    proc = subprocess.Popen([sys.executable, "-c", _STALLED_BATCH.format(root=str(ROOT), jobs=json.dumps(jobs))],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    deadline = time.monotonic() + 120
    while not all(Path(j["ready"]).exists() for j in jobs):
        assert proc.poll() is None and time.monotonic() < deadline, proc.communicate()
        time.sleep(0.05)
    assert len(hidden_entries(out)) >= 4  # two staging folders, one set aside, temporary batch.json files
    if signalled == "group":
        os.killpg(proc.pid, signal.SIGINT)
    else:
        proc.send_signal(signal.SIGINT)
    try:
        _, err = proc.communicate(timeout=60)
    except subprocess.TimeoutExpired:
        pytest.fail(f"the workers did not end: {end_group(proc.pid, 0.0)}")
    assert proc.returncode == 130 and err.strip().splitlines() == ["interrupted"], err
    assert end_group(proc.pid) == []
    assert hidden_entries(out) == []
    for name in ("staged", "half"):
        assert sorted(p.name for p in (out / name).iterdir()) == [DIR_MARKER, "report.json"]
        assert json.loads((out / name / "report.json").read_text()) == {"earlier": name}


def test_out_is_the_logs_folder_is_refused_before_any_work(fleet, tmp_path, capsys):
    assert cli.main(["batch", str(fleet), "--out", str(fleet), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and str(fleet) in err and "is the SPEC folder" in err, err
    assert sorted(p.name for p in fleet.iterdir()) == ["log1", "log2", "log3"]


def test_an_error_in_the_parent_ends_the_workers_at_once(tmp_path):
    """An exception while the logs run (here: from the callback of a finished log) stops the
    pool at once: the worker busy with a long log is ended, not waited for (it never gets to
    write the file it leaves after its sleep; no wall-clock comparison)."""
    import multiprocessing

    from gtvo.batching.runners import run_in_pool
    from tests._batch_tasks import pass_or_sleep

    def on_done(i, result):
        raise RuntimeError(f"cannot record log {i}")

    slept = tmp_path / "slept"
    with pytest.raises(RuntimeError, match="cannot record log 0"):
        run_in_pool([{"name": "quick"}, {"name": "long", "sleep": 120, "slept": str(slept)}], 2, on_done,
                    task=pass_or_sleep)
    assert multiprocessing.active_children() == []
    assert not slept.exists()  # ended during its sleep, not waited for
