"""docs/architecture.md and README.md name only what is there: every repository path they name
exists, every file a package row of the architecture's tree names is in that package, and every
dotted ``gtvo.`` / ``factors.`` name in backquotes imports."""

from __future__ import annotations

import importlib
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCS = ("docs/architecture.md", "README.md")
TOP = ("gtvo", "factors", "docs", "tests", "benchmarks", "examples", "data")

#: a path from the repository's root, written anywhere (``docs/window.md``, ``gtvo/io/outputs.py``);
#: not a part of a longer path (``../shared/data``, ``out/gtvo``)
ROOTED_PATH = re.compile(r"(?<![\w/.-])(?:" + "|".join(TOP) + r")/(?:[\w.-]+/)*[\w.-]*")
#: a backquoted path below gtvo/ without its prefix (`frontend/tracking.py`, `frontend/tracking.frame_pyramid`)
PACKAGE_PATH = re.compile(r"`((?:[a-z_]+/)+[a-z_]+)\.(py|[a-z_]+)`")
FILE_SUFFIXES = (".md", ".py", ".yaml", ".json", ".txt", ".npz", ".png")
#: a backquoted dotted name of the code (`gtvo.config.OdometryConfig`, `factors.smart.HostPointsFactor`)
DOTTED_NAME = re.compile(r"`((?:gtvo|factors)(?:\.[A-Za-z_]\w*)+)`")


def rooted_paths(text: str) -> set[str]:
    """Every path from the repository's root that ``text`` names (a trailing ``.`` is punctuation)."""
    return {m.rstrip(".") for m in ROOTED_PATH.findall(text)}


def package_paths(text: str) -> set[str]:
    """Backquoted paths below ``gtvo/`` written without it, as files: ``frontend/tracking.py``, and
    ``frontend/tracking.frame_pyramid`` when ``gtvo/frontend/`` exists (not ``out/config.yaml``)."""
    found = set()
    return {f"gtvo/{stem}.py" for stem, suffix in PACKAGE_PATH.findall(text)
            if stem.split("/")[0] not in TOP and (suffix == "py" or (ROOT / "gtvo" / stem.split("/")[0]).is_dir())}


def missing_names(text: str) -> list[str]:
    """Dotted names in backquotes that do not resolve: the longest importable module, then attributes."""
    missing = []
    for name in sorted(set(DOTTED_NAME.findall(text))):
        if name.endswith(FILE_SUFFIXES) or "__main__" in name:  # a file name; the module that runs the CLI
            continue
        parts = name.split(".")
        for cut in range(len(parts), 0, -1):
            try:
                obj = importlib.import_module(".".join(parts[:cut]))
            except ModuleNotFoundError:
                continue
            try:
                for attribute in parts[cut:]:
                    obj = getattr(obj, attribute)
            except AttributeError:
                missing.append(name)
            break
        else:
            missing.append(name)
    return missing


def tree_rows(text: str) -> list[tuple[list[str], list[str]]]:
    """(the folders and files a row is about, the file names it names) of each row of the architecture's tree table."""
    section = text.split("## The tree", 1)[1].split("\n## ", 1)[0]
    rows = []
    for line in section.splitlines():
        cells = line.strip().strip("|").split("|", 1)
        if len(cells) == 2 and cells[0].strip().startswith("`"):
            packages = re.findall(r"`([\w/.]+)`", cells[0])
            rows.append((packages, re.findall(r"`([\w]+\.py)`", cells[1])))
    return rows


@pytest.mark.parametrize("doc", DOCS)
def test_every_path_named_exists(doc: str) -> None:
    text = (ROOT / doc).read_text(encoding="utf-8")
    named = rooted_paths(text) | package_paths(text)
    assert named, f"no paths found in {doc}: the pattern is wrong"
    missing = sorted(p for p in named if not (ROOT / p).exists())
    assert not missing, f"{doc} names paths that do not exist: {missing}"


@pytest.mark.parametrize("doc", DOCS)
def test_every_dotted_name_imports(doc: str) -> None:
    missing = missing_names((ROOT / doc).read_text(encoding="utf-8"))
    assert not missing, f"{doc} names modules or attributes that do not exist: {missing}"


def test_every_file_of_a_tree_row_is_in_its_package() -> None:
    rows = tree_rows((ROOT / "docs" / "architecture.md").read_text(encoding="utf-8"))
    assert len(rows) >= 10
    missing = [f"{packages}: {name}" for packages, names in rows for name in names
               if not any((ROOT / p / name).exists() or p.endswith("/" + name) for p in packages)]
    assert not missing, f"docs/architecture.md's tree names files its packages do not hold: {missing}"


def test_the_checks_see_a_stale_path() -> None:
    """The patterns find what the docs write (so a stale name cannot hide from them)."""
    text = ("see docs/window.md, `gtvo/odometry.py` and `frontend/gone.py`, `gtvo.window.NoSuchThing`; "
            "not ../shared/data, `gtvo_out/demo`, `out/config.yaml`, `factors.md`")
    assert rooted_paths(text) == {"docs/window.md", "gtvo/odometry.py"}
    assert package_paths(text) == {"gtvo/frontend/gone.py"}
    assert missing_names(text) == ["gtvo.window.NoSuchThing"]
    rows = tree_rows("## The tree\n| package | what |\n|---|---|\n| `gtvo/io/` | writes (`gone.py`) |\n")
    assert rows == [(["gtvo/io/"], ["gone.py"])]
