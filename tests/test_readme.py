"""README.md stays readable and true, and docs/ stays free of the project's bookkeeping: no
paragraph over 15 lines, every ``gtvo ...`` command of the README's code blocks names a subcommand
and flags the CLI has (read from its argparse parser), every dataset format named, no issue
numbers in README.md or docs/, and docs/benchmarks.md short enough to read."""

from __future__ import annotations

import argparse
import re
import shlex
from pathlib import Path

import pytest

from gtvo.cli import build_parser
from gtvo.datasets import FORMATS

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
MAX_PARAGRAPH_LINES = 15
MAX_BENCHMARK_LINES = 700
#: "issue 24", "issues 21 and 30", "issue-21", "#34": the tracker's numbers mean nothing to a reader
ISSUE_NUMBER = re.compile(r"\bissues? \d+|\bissue-\d+|(?<![\w&])#\d+\b", re.IGNORECASE)


def paragraphs(text: str) -> list[tuple[int, list[str]]]:
    """``(first line number, lines)`` of every paragraph: consecutive non-blank lines outside code
    fences, headings apart."""
    found: list[tuple[int, list[str]]] = []
    current: list[str] = []
    start, fenced = 0, False
    for number, line in enumerate(text.splitlines(), 1):
        if line.startswith("```"):
            fenced = not fenced
        if fenced or line.startswith("```") or not line.strip() or line.startswith("#"):
            if current:
                found.append((start, current))
            current = []
            continue
        if not current:
            start = number
        current.append(line)
    if current:
        found.append((start, current))
    return found


def code_block_commands(text: str) -> list[str]:
    """Every line of a code block that runs ``gtvo`` (comments dropped)."""
    commands, fenced = [], False
    for line in text.splitlines():
        if line.startswith("```"):
            fenced = not fenced
            continue
        if fenced and line.startswith("gtvo "):
            commands.append(line)
    return commands


def _subcommands(parser: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    return next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction)).choices


def unknown_words(command: str, parser: argparse.ArgumentParser) -> list[str]:
    """The subcommand or flags of ``command`` the CLI does not have (empty: all exist)."""
    words = [w.strip("[]") for w in shlex.split(command, comments=True)][1:]
    top = {flag for action in parser._actions for flag in action.option_strings}
    if not words or words[0] in top:
        return [w for w in words if w.startswith("--") and w.split("=")[0] not in top]
    commands = _subcommands(parser)
    if words[0] not in commands:
        return [words[0]]
    flags = {flag for action in commands[words[0]]._actions for flag in action.option_strings}
    return [w for w in words[1:] if w.startswith("-") and w != "-" and w.split("=")[0] not in flags]


def test_paragraph_and_command_helpers_find_what_they_should():
    text = "# T\n\none\ntwo\n\n```bash\ngtvo run X --nope  # --out\n```\nthree\n"
    assert paragraphs(text) == [(3, ["one", "two"]), (9, ["three"])]
    assert code_block_commands(text) == ["gtvo run X --nope  # --out"]
    parser = build_parser()
    assert unknown_words("gtvo run X --nope  # --out", parser) == ["--nope"]
    assert unknown_words("gtvo runn X", parser) == ["runn"]
    assert unknown_words("gtvo demo [--out DIR]", parser) == []


def test_no_readme_paragraph_is_longer_than_15_lines():
    long = [(start, len(lines)) for start, lines in paragraphs(README.read_text(encoding="utf-8"))
            if len(lines) > MAX_PARAGRAPH_LINES]
    assert not long, f"README.md paragraphs (first line, lines) over {MAX_PARAGRAPH_LINES} lines: {long}"


def test_every_readme_command_names_a_subcommand_and_flags_the_cli_has():
    parser = build_parser()
    commands = code_block_commands(README.read_text(encoding="utf-8"))
    assert len(commands) > 20  # the Use block
    wrong = {c: unknown_words(c, parser) for c in commands if unknown_words(c, parser)}
    assert not wrong, wrong
    used = {shlex.split(c, comments=True)[1] for c in commands}
    assert set(_subcommands(parser)) <= used  # every subcommand shown once at least


def test_the_readme_names_every_dataset_format():
    text = README.read_text(encoding="utf-8")
    assert all(f"`{name}`" in text for name in FORMATS), [n for n in FORMATS if f"`{name}`" not in text]


@pytest.mark.parametrize("path", [README, *sorted((ROOT / "docs").glob("*.md"))], ids=lambda p: p.name)
def test_no_issue_numbers_in_the_docs(path):
    hits = [f"{path.name}:{n}: {m.group(0)}" for n, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1)
            for m in ISSUE_NUMBER.finditer(line)]
    assert not hits, hits


def test_the_issue_pattern_catches_the_forms_used_before():
    for text in ("issue 24", "Issues 21 and 30", "the issue-21 tables", "see #34"):
        assert ISSUE_NUMBER.search(text), text
    for text in ("KITTI 00", "frame 24", "&#39;", "sequence_1", "`a#1`"):
        assert not ISSUE_NUMBER.search(text), text


def test_benchmarks_page_is_at_most_700_lines():
    lines = (ROOT / "docs" / "benchmarks.md").read_text(encoding="utf-8").count("\n")
    assert lines <= MAX_BENCHMARK_LINES, lines


def test_every_format_synopsis_in_the_docs_lists_the_registry_formats():
    synopsis = re.compile(r"gtvo (?:run|info|loops)\b[^\n`]*--format ([a-z_]+(?:\|[a-z_]+)+)")
    found = {path.name: m.group(1) for path in [README, *sorted((ROOT / "docs").glob("*.md"))]
             for m in synopsis.finditer(path.read_text(encoding="utf-8"))}
    assert found  # docs/loop_closure.md has one
    assert all(v.split("|") == ["auto", *FORMATS] for v in found.values()), found
