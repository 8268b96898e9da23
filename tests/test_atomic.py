import json
import os
import stat
from pathlib import Path

import pytest

from gtvo.core.atomic import (DIR_MARKER, atomic_dir, atomic_open, check_output_file, ensure_output_dir,
                         tidy_on_failure, write_json, write_text)
from gtvo.errors import InputError


def test_write_replaces_atomically(tmp_path):
    p = tmp_path / "out.txt"
    write_text(p, "old\n")
    with pytest.raises(RuntimeError):
        with atomic_open(p) as f:
            f.write("half of the new")
            raise RuntimeError("interrupted")
    assert p.read_text() == "old\n"
    assert sorted(os.listdir(tmp_path)) == ["out.txt"]  # no temp file left behind


def test_write_json_refuses_nan_and_keeps_old(tmp_path):
    p = tmp_path / "r.json"
    write_json(p, {"a": 1})
    with pytest.raises(ValueError):
        write_json(p, {"a": float("nan")})
    assert json.loads(p.read_text()) == {"a": 1}
    assert sorted(os.listdir(tmp_path)) == ["r.json"]


def test_permissions_like_open(tmp_path):
    p = tmp_path / "x.txt"
    write_text(p, "x")
    umask = os.umask(0)
    os.umask(umask)
    assert stat.S_IMODE(p.stat().st_mode) == 0o666 & ~umask


LAYOUT = frozenset({"data.txt", "frames"})


def _write(tmp, n):
    (tmp / "data.txt").write_text(str(n))
    (tmp / "frames").mkdir()
    for i in range(n):
        (tmp / "frames" / f"{i}.txt").write_text(str(i))


def test_atomic_dir_replaces_its_own_output_as_a_whole(tmp_path):
    out = tmp_path / "out"
    with atomic_dir(out, LAYOUT, "the test") as tmp:
        _write(tmp, 4)
    with atomic_dir(out, LAYOUT, "the test") as tmp:
        _write(tmp, 2)
    assert sorted(p.name for p in (out / "frames").iterdir()) == ["0.txt", "1.txt"]
    assert (out / DIR_MARKER).is_file()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]  # no temporary folders left


def test_atomic_dir_never_deletes_what_it_did_not_write(tmp_path):
    """A folder with the same layout but no marker (a real dataset), a folder with extra files,
    files added while the new output is written, the current folder: all refused, all intact."""
    real = tmp_path / "real"
    real.mkdir()
    _write(real, 3)
    with pytest.raises(InputError, match="not written by the test"):
        with atomic_dir(real, LAYOUT, "the test") as tmp:
            _write(tmp, 1)
    assert len(list((real / "frames").iterdir())) == 3
    out = tmp_path / "out"
    with atomic_dir(out, LAYOUT, "the test") as tmp:
        _write(tmp, 2)
    with pytest.raises(InputError, match="other files"):
        with atomic_dir(out, LAYOUT, "the test") as tmp:
            (out / "notes.txt").write_text("mine")  # written during the (long) render
            _write(tmp, 1)
    assert (out / "notes.txt").read_text() == "mine" and len(list((out / "frames").iterdir())) == 2
    cwd = os.getcwd()
    try:
        os.chdir(out)
        for name in (".", str(out.parent)):
            with pytest.raises(InputError, match="current folder"):
                with atomic_dir(name, LAYOUT, "the test"):
                    pass
    finally:
        os.chdir(cwd)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out", "real"]


def test_output_checks_name_the_path(tmp_path):
    f = tmp_path / "f"
    f.write_text("x")
    with pytest.raises(InputError, match="output folder is a file"):
        ensure_output_dir(f)
    with pytest.raises(InputError, match="is a folder"):
        check_output_file(tmp_path)
    assert check_output_file(tmp_path / "new" / "x.json") == tmp_path / "new" / "x.json"
    assert (tmp_path / "new").is_dir()



def test_tidy_on_failure_removes_only_the_empty_folders_it_made(tmp_path):
    (tmp_path / "old").mkdir()
    with pytest.raises(RuntimeError):
        with tidy_on_failure():
            ensure_output_dir(tmp_path / "old" / "a" / "b")
            ensure_output_dir(tmp_path / "c")
            (tmp_path / "c" / "user.txt").write_text("kept")
            raise RuntimeError("the work failed")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["c", "old"]  # c holds a file: kept
    assert list((tmp_path / "old").iterdir()) == []  # a/b removed, the folder that existed kept
    with tidy_on_failure():  # success: nothing is removed
        ensure_output_dir(tmp_path / "d" / "e")
    assert (tmp_path / "d" / "e").is_dir()


def test_tidy_on_failure_keeps_an_existing_folder_reached_through_dotdot(tmp_path, monkeypatch):
    (tmp_path / "e").mkdir()
    monkeypatch.chdir(tmp_path)
    with pytest.raises(RuntimeError):
        with tidy_on_failure():
            ensure_output_dir("n/../e")  # 'n' is made by mkdir(parents=True); 'e' existed
            raise RuntimeError("the work failed")
    assert (tmp_path / "e").is_dir()


def test_tidy_on_failure_nested_blocks_hand_their_folders_to_the_outer_one(tmp_path):
    with pytest.raises(KeyboardInterrupt):
        with tidy_on_failure():
            with tidy_on_failure():
                ensure_output_dir(tmp_path / "a" / "b")
            assert (tmp_path / "a" / "b").is_dir()
            raise KeyboardInterrupt
    assert list(tmp_path.iterdir()) == []


def test_output_lock_lets_one_writer_in_whatever_the_spelling(tmp_path):
    """A second writer of one output folder is refused at once with one line (before: both ran and
    the later one replaced the earlier one's outputs, each reporting success); the lock is the
    folder's real path's, so a link to it or '..' reaches the same lock; released when the block ends."""
    from gtvo.core.atomic import output_lock

    out = tmp_path / "runs" / "out"
    (tmp_path / "alias").symlink_to(tmp_path / "runs")
    with output_lock(out) as held:
        assert held == out.resolve() and (tmp_path / "runs" / ".out.lock").read_text().strip() == str(os.getpid())
        for spelling in (out, tmp_path / "alias" / "out", tmp_path / "runs" / "x" / ".." / "out"):
            with pytest.raises(InputError, match=r"another gtvo process \(pid \d+\) is writing into this output "
                                                 r"folder") as info:
                with output_lock(spelling):
                    pass
            assert "\n" not in str(info.value)
        with output_lock(tmp_path / "runs" / "other"):  # another folder: its own lock
            pass
    assert sorted(p.name for p in (tmp_path / "runs").iterdir()) == []  # no lock file left
    with output_lock(out):  # released
        pass


def test_output_lock_holds_across_processes(tmp_path):
    import subprocess
    import sys

    from gtvo.core.atomic import output_lock

    out = tmp_path / "out"
    code = ("import sys; from gtvo.core.atomic import output_lock\n"
            "try:\n    with output_lock(sys.argv[1]): pass\nexcept Exception as e: print(e); sys.exit(2)\n")
    with output_lock(out):
        r = subprocess.run([sys.executable, "-c", code, str(out)], capture_output=True, text=True, timeout=300)
    assert r.returncode == 2 and "another gtvo process" in r.stdout, r
    r = subprocess.run([sys.executable, "-c", code, str(out)], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r


def test_output_lock_removes_what_a_killed_writer_left_and_nothing_else(tmp_path):
    """A run killed (SIGTERM, SIGKILL: no ``finally``) while writing leaves its hidden staging
    folder beside the output folder; the next writer, holding the lock, removes it, puts a set
    that was moved aside back, and leaves everything that is not gtvo's own staging alone."""
    import tempfile

    from gtvo.core.atomic import output_lock

    runs = tmp_path / "runs"
    out = runs / "out"
    out.mkdir(parents=True)
    (out / DIR_MARKER).write_text("written by gtvo run\n")
    (out / "trajectory.tum").write_text("earlier\n")
    staged = Path(tempfile.mkdtemp(prefix=".out.", dir=runs))
    (staged / "trajectory.tum").write_text("half\n")
    temp_file = Path(tempfile.mkstemp(prefix=".summary.json.", suffix=".json", dir=out)[1])
    keep = [runs / ".out.notes", runs / ".other.abcdefgh", runs / "out.abcdefgh", out / ".mine"]
    for p in keep:
        p.mkdir()
    with output_lock(out, file_names=("summary.json",)):
        assert not staged.exists() and not temp_file.exists()
    assert all(p.exists() for p in keep) and (out / "trajectory.tum").read_text() == "earlier\n"


def test_a_killed_writers_lock_file_is_discarded_a_held_one_is_not(tmp_path):
    from gtvo.core.atomic import discard_unfinished, output_lock

    out = tmp_path / "out"
    (tmp_path / ".out.lock").write_text("12345\n")  # its writer was killed: nothing holds it
    assert discard_unfinished([out]) == [tmp_path / ".out.lock"] and not (tmp_path / ".out.lock").exists()
    with output_lock(out):
        assert discard_unfinished([out]) == [] and (tmp_path / ".out.lock").exists()
