"""The one-way layers of docs/architecture.md, checked on every import of gtvo/ and factors/.

Every ``import`` / ``from ... import`` of a gtvo or factors module (found with ``ast``, at any
depth: imports inside functions count too) must go from a layer to one that the table in
docs/architecture.md ("Layers") allows, and the modules must not import each other in a cycle.
The table is read from the doc itself, so the doc and the code cannot drift apart.
"""

from __future__ import annotations

import ast
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
DOC = ROOT / "docs" / "architecture.md"


def layer_of(module: str) -> str:
    """The layer of a dotted module name: ``factors``, ``gtvo`` (the package's top) or ``gtvo.X``."""
    parts = module.split(".")
    if parts[0] == "factors":
        return "factors"
    if module == "gtvo":
        return "gtvo"
    return "gtvo." + parts[1]


def allowed_table() -> dict[str, set[str]]:
    """``layer -> layers it may import``, from the table under "## Layers" in docs/architecture.md."""
    text = DOC.read_text(encoding="utf-8")
    section = text.split("## Layers", 1)[1].split("\n## ", 1)[0]
    table: dict[str, set[str]] = {}
    for line in section.splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if len(cells) < 2 or not cells[0].startswith("`"):
            continue
        layer = cells[0].strip("`")
        table[layer] = set(re.findall(r"`([a-z_.]+)`", cells[1]))
    return table


def module_name(path: Path, root: Path = ROOT) -> str:
    """The dotted module name of a source file below ``root`` (the checkout)."""
    parts = list(path.relative_to(root).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(parts)


def imports_of(path: Path, root: Path = ROOT) -> set[str]:
    """Every gtvo / factors module that ``path`` (below ``root``) imports (absolute imports; relative
    ones resolved)."""
    found: set[str] = set()
    package = module_name(path, root).split(".")
    if path.name != "__init__.py":
        package = package[:-1]
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            found.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                base = ".".join(package[:len(package) - node.level + 1] + ([base] if base else []))
            found.add(base)
            found.update(f"{base}.{a.name}" for a in node.names)  # `from gtvo.window import problem`
    return {m for m in found if m.split(".")[0] in ("gtvo", "factors")}


def source_files() -> list[Path]:
    return sorted(p for top in ("gtvo", "factors") for p in (ROOT / top).rglob("*.py"))


def existing_modules() -> set[str]:
    return {module_name(p) for p in source_files()}


def test_the_doc_has_a_row_for_every_layer() -> None:
    table = allowed_table()
    layers = {layer_of(module_name(p)) for p in source_files()}
    assert layers - set(table) == set(), f"layers missing from docs/architecture.md: {layers - set(table)}"


def test_every_import_goes_the_way_the_doc_allows() -> None:
    table = allowed_table()
    modules = existing_modules()
    wrong = []
    for path in source_files():
        src = layer_of(module_name(path))
        for target in imports_of(path):
            if target not in modules:  # `from gtvo.x import name`: the name is not a module
                continue
            dst = layer_of(target)
            if dst != src and dst not in table.get(src, set()) and dst != "gtvo.errors":
                wrong.append(f"{path.relative_to(ROOT)} ({src}) imports {target} ({dst})")
    assert not wrong, "imports against docs/architecture.md 'Layers':\n" + "\n".join(wrong)


def test_the_core_and_factors_stay_at_the_bottom() -> None:
    """The issue's own rule, independent of the doc: core imports no other gtvo layer, factors only core."""
    table = allowed_table()
    assert table["gtvo.core"] <= {"gtvo.errors"}
    assert table["factors"] <= {"gtvo.core", "gtvo.errors"}


def test_the_report_and_the_settings_sit_below_what_fills_them() -> None:
    """Independent of the doc: ``gtvo/report.py`` (the report's types) imports no writer, odometry,
    loop closing, refinement or pipeline (they import their part's type from it), and the settings
    (``gtvo/config/``) import only the core and the factors' parameters."""
    above = {"gtvo.io", "gtvo.odometry", "gtvo.loops", "gtvo.refinement", "gtvo.pipeline", "gtvo.batching",
             "gtvo.commands"}
    report = {layer_of(m) for m in imports_of(ROOT / "gtvo" / "report.py")}
    assert report & above == set(), f"gtvo/report.py imports {sorted(report & above)}"
    settings = {m for p in (ROOT / "gtvo" / "config").rglob("*.py") for m in imports_of(p)}
    assert {layer_of(m) for m in settings} <= {"gtvo.config", "gtvo.core", "gtvo.errors", "factors"}
    assert {m for m in settings if layer_of(m) == "factors"} <= {"factors.params", "factors.params.PhotometricConfig"}
    table = allowed_table()
    assert table["gtvo.report"] & above == set() and table["gtvo.config"] <= {"factors", "gtvo.core"}


def test_no_import_cycle_between_modules() -> None:
    modules = existing_modules()
    graph = {module_name(p): {m for m in imports_of(p) if m in modules and m != module_name(p)}
             for p in source_files()}
    # a package's __init__ importing its own submodules is how a package is built, not a cycle
    for mod, deps in graph.items():
        graph[mod] = {d for d in deps if not mod.startswith(d + ".")}
    state: dict[str, int] = {}
    stack: list[str] = []

    def visit(m: str) -> list[str] | None:
        state[m] = 1
        stack.append(m)
        for d in sorted(graph.get(m, ())):
            if state.get(d) == 1:
                return stack[stack.index(d):] + [d]
            if d not in state:
                cycle = visit(d)
                if cycle:
                    return cycle
        stack.pop()
        state[m] = 2
        return None

    for m in sorted(graph):
        if m not in state:
            cycle = visit(m)
            assert cycle is None, "import cycle: " + " -> ".join(cycle)


def test_the_checker_sees_a_forbidden_import(tmp_path: Path) -> None:
    """The walk finds imports inside functions and relative imports (so a violation cannot hide);
    the probe is a module of a ``factors/`` package in a scratch tree, never in the checkout."""
    probe = tmp_path / "factors" / "_layer_probe.py"
    probe.parent.mkdir()
    probe.write_text("def f():\n    from gtvo.odometry import VisualOdometry\n    from . import photometric\n")
    found = imports_of(probe, root=tmp_path)
    assert "gtvo.odometry" in found and "factors.photometric" in found
    assert layer_of(module_name(probe, root=tmp_path)) == "factors"
