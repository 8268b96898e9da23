import json
import os
import stat

import pytest

from gtvo.atomic import atomic_open, write_json, write_text


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
