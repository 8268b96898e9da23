"""The test suite's own set-up (pyproject's [tool.pytest.ini_options]): plugins that warn or
write into the checkout are off, and the quick lane (``pytest -m "not slow"``) keeps tests of
every module."""

from __future__ import annotations

import ast
import importlib.util
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
#: modules whose every test is slow on purpose: the benchmark peers' one test runs each peer on KITTI
ALL_SLOW = {"test_peers_benchmark.py"}


@pytest.mark.slow
def test_plugins_neither_warn_nor_write_into_the_checkout(tmp_path: Path) -> None:
    """A trivial suite under this pyproject, warnings all shown: no plugin's warning, no ``.benchmarks/``."""
    plugins = [name for name in ("dash", "pytest_benchmark") if importlib.util.find_spec(name)]
    if not plugins:
        pytest.skip("neither dash nor pytest-benchmark is installed: nothing to quiet")
    (tmp_path / "pyproject.toml").write_text((ROOT / "pyproject.toml").read_text(encoding="utf-8"))
    (tmp_path / "tests").mkdir()
    (tmp_path / "tests" / "test_probe.py").write_text("def test_probe():\n    pass\n")
    env = dict(os.environ, PYTHONWARNINGS="always")
    done = subprocess.run([sys.executable, "-m", "pytest", "-p", "no:cacheprovider"], cwd=tmp_path, env=env,
                          capture_output=True, text=True, timeout=120)
    output = done.stdout + done.stderr
    assert done.returncode == 0, output
    assert "Warning" not in output, output
    assert not (tmp_path / ".benchmarks").exists()


def marked_slow(decorators: list[ast.expr]) -> bool:
    """Whether one of the decorators (or a ``pytestmark``'s value) is ``pytest.mark.slow``."""
    return any("mark.slow" in ast.unparse(d) for d in decorators)


def test_the_quick_lane_keeps_tests_of_every_module() -> None:
    without_quick_tests = []
    for path in sorted((ROOT / "tests").glob("test_*.py")):
        tree = ast.parse(path.read_text(encoding="utf-8"))
        module_slow = any(isinstance(node, ast.Assign) and marked_slow([node.value])
                          and any(getattr(t, "id", "") == "pytestmark" for t in node.targets) for node in tree.body)
        quick = [node.name for node in ast.walk(tree) if isinstance(node, ast.FunctionDef)
                 and node.name.startswith("test_") and not marked_slow(node.decorator_list)]
        if (module_slow or not quick) and path.name not in ALL_SLOW:
            without_quick_tests.append(path.name)
    assert not without_quick_tests, f"modules with no test in the quick lane: {without_quick_tests}"
