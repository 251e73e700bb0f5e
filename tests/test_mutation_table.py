"""tools/mutations.py stays runnable: every break still applies to the tree (its text occurs exactly once in its
file, inside one line) and names test files that exist, so docs/testing.md's table can be re-run
(`python tools/mutation_check.py`). A refactor that moves a guarded line makes this fail: move the entry too."""

from __future__ import annotations

import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tools"))

from mutation_check import problem  # noqa: E402
from mutations import MUTATIONS  # noqa: E402


def test_every_break_applies_to_the_tree():
    problems = [f"{m.name}: {p}" for m in MUTATIONS if (p := problem(m)) is not None]
    assert not problems, "\n".join(problems)


def test_every_break_changes_its_line_and_names_are_unique():
    assert all(m.old != m.new and m.tests for m in MUTATIONS)
    names = [m.name for m in MUTATIONS]
    assert len(names) == len(set(names))


def test_the_table_in_docs_lists_every_entry():
    doc = (ROOT / "docs" / "testing.md").read_text()
    missing = [m.name for m in MUTATIONS if f"`{m.name}`" not in doc]
    assert not missing, f"docs/testing.md has no row for {missing}"
