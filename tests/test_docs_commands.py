"""No figure in README.md, CONTRIBUTING.md or docs/*.md names a command a reader cannot run (issue 30 item 18: every
figure from a command a reader can run; issue 29: figures in docs/, history in git). Sessions left ~40 figures whose
command was a script under /tmp or /work/notes, gone with the session that wrote it.

The rule (docs/testing.md "Commands in the docs"):
- No path under `/work/notes/`: the sessions' notes are not part of the repository.
- A path under `/tmp/` appears only inside code (a code span or a fenced block): a command a reader types, with
  /tmp as a scratch place it writes to and reads back (`--stats-file /tmp/stats.json`, `AHRSD_CPU_TIME_OUT=/tmp/cpu`).
  In prose it names a file the reader does not have.
- Even in code, a /tmp path is never a script or a patch (`.py`, `.sh`, `.patch`, `.diff`): the script behind a
  figure lives in bench/ or tools/. A diagnostic that was not kept is said to be so, without a path."""

import pathlib
import re

import pytest

ROOT = pathlib.Path(__file__).resolve().parent.parent
PAGES = [ROOT / "README.md", ROOT / "CONTRIBUTING.md", *sorted((ROOT / "docs").glob("*.md"))]

_FENCE = re.compile(r"^\s*(```|~~~)")
# a code span: backticks, then anything up to the same run of backticks, within one paragraph (no blank line)
_CODE_SPAN = re.compile(r"(`+)((?:(?!\n\s*\n).)+?)\1", re.DOTALL)
_TMP_PATH = re.compile(r"(?<![\w.~/-])/tmp/[^\s`'\"),;]*")
_SCRIPT = re.compile(r"\.(py|sh|patch|diff)$")


def _code_mask(text):
    """One bool per character of `text`: inside a fenced block or a code span."""
    mask = [False] * len(text)
    inside, start, prose = False, 0, []
    for line in text.splitlines(keepends=True):
        end = start + len(line)
        if _FENCE.match(line):
            inside = not inside
            mask[start:end] = [True] * len(line)
        elif inside:
            mask[start:end] = [True] * len(line)
        else:
            prose.append((start, end))
        start = end
    # code spans, over the runs of consecutive prose lines (a span may wrap onto the next line)
    runs, run_start, run_end = [], None, None
    for s, e in prose:
        if run_end == s:
            run_end = e
        else:
            if run_start is not None:
                runs.append((run_start, run_end))
            run_start, run_end = s, e
    if run_start is not None:
        runs.append((run_start, run_end))
    for s, e in runs:
        for match in _CODE_SPAN.finditer(text, s, e):
            mask[match.start():match.end()] = [True] * (match.end() - match.start())
    return mask


def unrunnable_commands(page):
    """Each place a page breaks the rule: '<file>:<line>: <path>: <why>'."""
    text = page.read_text(encoding="utf-8")
    mask = _code_mask(text)
    line_of = lambda pos: text.count("\n", 0, pos) + 1  # noqa: E731
    problems = []
    for match in re.finditer(r"/work/notes/[^\s`'\"),;]+", text):
        problems.append(f"{page.name}:{line_of(match.start())}: {match.group(0)}: the sessions' notes are not in "
                        f"the repository")
    for match in _TMP_PATH.finditer(text):
        path = match.group(0).rstrip(".:")
        if not mask[match.start()]:
            problems.append(f"{page.name}:{line_of(match.start())}: {path}: a /tmp path in prose")
        elif _SCRIPT.search(path):
            problems.append(f"{page.name}:{line_of(match.start())}: {path}: a script under /tmp")
    return problems


@pytest.mark.parametrize("page", PAGES, ids=lambda p: str(p.relative_to(ROOT)))
def test_no_figure_names_a_command_outside_the_repository(page):
    assert unrunnable_commands(page) == []


def test_the_rule_finds_what_it_should_and_lets_scratch_files_be(tmp_path):
    """The checker itself, on a constructed page: the forbidden forms found, with their lines; the allowed ones
    (a scratch file in a typed command, in a span, a wrapped span and a fence) not."""
    page = tmp_path / "page.md"
    page.write_text(
        "# Page\n\n"
        "Run `ahrsd run --stats-file /tmp/stats.json` and read it.\n"            # 3: allowed
        "The figure (`/tmp/x/diag.py 600`, load 3).\n"                            # 4: script in a span
        "Outputs in /tmp/lead/rows.txt, not kept.\n"                              # 5: prose
        "Notes (`/work/notes/s1/run.txt`).\n"                                     # 6: notes
        "A wrapped span (`git clone -q repo\n/tmp/walk/ahrsd`, 10 min).\n"        # 7-8: allowed
        "A wrapped script (`python\n/tmp/a/b.sh 1`).\n\n"                         # 9-10: script
        "```\nAHRSD_CPU_TIME_OUT=/tmp/cpu pytest\npython tools/x.py /tmp/cpu-*.jsonl\n```\n"   # 12-14: allowed
        "```\npatch -p1 < /tmp/fix.patch\n```\n",                                 # 17: patch in a fence
        encoding="utf-8",
    )
    assert unrunnable_commands(page) == [
        "page.md:6: /work/notes/s1/run.txt: the sessions' notes are not in the repository",
        "page.md:4: /tmp/x/diag.py: a script under /tmp",
        "page.md:5: /tmp/lead/rows.txt: a /tmp path in prose",
        "page.md:10: /tmp/a/b.sh: a script under /tmp",
        "page.md:17: /tmp/fix.patch: a script under /tmp",
    ]
