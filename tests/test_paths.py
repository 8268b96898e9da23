"""gtvo/core/paths.py: paths resolved without a traceback, folders compared by file identity."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from gtvo.core.paths import identity, link_problem, resolved, same_or_inside
from gtvo.errors import InputError


def test_a_symbolic_link_loop_is_one_line_naming_it(tmp_path):
    loop = tmp_path / "loop"
    loop.symlink_to("loop")
    with pytest.raises(InputError, match=r"loop: output folder is a symbolic link loop$") as info:
        resolved(loop, "output folder")
    assert str(loop) in str(info.value) and "\n" not in str(info.value)
    with pytest.raises(InputError, match="symbolic link loop"):
        resolved(loop / "inside")
    assert resolved(tmp_path / "new" / ".." / "x") == tmp_path.resolve() / "x"


def test_link_problem_tells_loops_and_broken_links_from_plain_paths(tmp_path):
    (tmp_path / "a").symlink_to("b")
    (tmp_path / "b").symlink_to("a")
    (tmp_path / "gone").symlink_to("nowhere")
    (tmp_path / "dir").mkdir()
    (tmp_path / "ok").symlink_to("dir")
    assert link_problem(tmp_path / "a") == "a symbolic link loop"
    assert link_problem(tmp_path / "gone") == "a broken symbolic link (to nowhere)"
    assert link_problem(tmp_path / "ok") is None
    assert link_problem(tmp_path / "dir") is None
    assert link_problem(tmp_path / "absent") is None


def test_same_or_inside_whatever_the_spelling(tmp_path):
    log = tmp_path / "logs" / "logA"
    (log / "image_0").mkdir(parents=True)
    (tmp_path / "alias").symlink_to(log)
    (tmp_path / "logs" / "logB").mkdir()
    assert same_or_inside(log, log)
    assert same_or_inside(tmp_path / "alias", log)  # a link to it
    assert same_or_inside(tmp_path / "alias" / "out" / "new", log)  # not yet made, below a link to it
    assert same_or_inside(tmp_path / "logs" / "logB" / ".." / "logA" / "x", log)  # '..'
    assert same_or_inside(log / "image_0", log) and not same_or_inside(log, log / "image_0")
    assert not same_or_inside(tmp_path / "logs" / "logB", log)
    assert not same_or_inside(tmp_path / "logs" / "logA2", log)  # a name that starts alike is another folder
    assert not same_or_inside(log, tmp_path / "absent")
    assert identity(tmp_path / "alias") == identity(log) and identity(tmp_path / "absent") is None


@pytest.mark.skipif(not Path("/proc/self/mountinfo").exists(), reason="Linux only")
def test_same_or_inside_sees_through_a_bind_mount(tmp_path):
    """A bind mount shows one folder under two paths that no string comparison relates; the
    device and inode numbers are the same (needs the right to mount: skipped without it)."""
    import subprocess

    log = tmp_path / "log"
    (log / "image_0").mkdir(parents=True)
    mount = tmp_path / "mnt"
    mount.mkdir()
    r = subprocess.run(["mount", "--bind", str(log), str(mount)], capture_output=True)
    if r.returncode != 0:
        pytest.skip("cannot bind-mount here")
    try:
        assert os.path.realpath(mount) != os.path.realpath(log)
        assert same_or_inside(mount / "out", log) and same_or_inside(mount / "image_0", log / "image_0")
    finally:
        subprocess.run(["umount", str(mount)], check=True)
