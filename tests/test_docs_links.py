"""Every relative link and #anchor in README.md, CONTRIBUTING.md and docs/*.md resolves (issue 30, session 25: the
README was shortened and its detail moved into docs/, so its links now carry the reader; a link to a file or a
heading that is not there is a dead end).

A link is `[text](target)` outside fenced code blocks and code spans; web addresses are not fetched. The target's
file must exist (relative to the linking file), and an anchor must be the slug of one of its headings as GitHub
renders it: the heading's text lower-cased, characters other than letters, digits, spaces, `-` and `_` dropped,
spaces turned into `-`, and a repeated slug numbered `-1`, `-2` … (github-slugger, which github.com uses)."""

import pathlib
import re

import pytest

ROOT = pathlib.Path(__file__).resolve().parent.parent
PAGES = [ROOT / "README.md", ROOT / "CONTRIBUTING.md", *sorted((ROOT / "docs").glob("*.md"))]

_FENCE = re.compile(r"^\s*(```|~~~)")
_HEADING = re.compile(r"^(#{1,6})\s+(.*?)\s*#*\s*$")
_CODE_SPAN = re.compile(r"(`+)(.+?)\1")
# [text](target) or [text](target "title"); text may hold code spans and brackets one level deep
_LINK = re.compile(r"\[(?:[^\[\]]|\[[^\[\]]*\])*\]\(\s*<?([^)\s>]+)>?(?:\s+\"[^\"]*\")?\s*\)")


def _prose_lines(text):
    """(line number, line) of the lines outside fenced code blocks."""
    inside = False
    for number, line in enumerate(text.splitlines(), 1):
        if _FENCE.match(line):
            inside = not inside
            continue
        if not inside:
            yield number, line


def github_slug(heading):
    """The anchor GitHub gives a heading's text (before the -1, -2 … of repeats)."""
    text = _CODE_SPAN.sub(lambda m: m.group(2), heading)  # a code span's content is kept, its backticks dropped
    text = re.sub(r"\[([^\]]*)\]\([^)]*\)", r"\1", text)  # a link in a heading: its text
    text = text.lower()
    text = "".join(ch for ch in text if ch.isalnum() or ch in " -_")
    return text.replace(" ", "-")


def anchors(path):
    """Every anchor a page's headings give, repeats numbered as GitHub numbers them."""
    seen = {}
    result = set()
    for _, line in _prose_lines(path.read_text(encoding="utf-8")):
        match = _HEADING.match(line)
        if not match:
            continue
        slug = github_slug(match.group(2))
        count = seen.get(slug, 0)
        seen[slug] = count + 1
        result.add(slug if count == 0 else f"{slug}-{count}")
    return result


def links(path):
    """(line number, target) of every link on a page, code spans and fenced code left out."""
    for number, line in _prose_lines(path.read_text(encoding="utf-8")):
        prose = _CODE_SPAN.sub(lambda m: "`" + "x" * len(m.group(2)) + "`", line)
        for match in _LINK.finditer(prose):
            yield number, match.group(1)


def broken_links(page):
    """What is wrong with each relative link of one page: '<line>: <target>: <why>'."""
    problems = []
    for number, target in links(page):
        if re.match(r"^[a-z][a-z0-9+.-]*:", target):  # http:, https:, mailto: … not checked here
            continue
        file_part, _, anchor = target.partition("#")
        linked = (page.parent / file_part).resolve() if file_part else page
        if not linked.exists():
            problems.append(f"{page.name}:{number}: {target}: no such file")
            continue
        if anchor and linked.suffix == ".md" and anchor not in anchors(linked):
            problems.append(f"{page.name}:{number}: {target}: no heading gives #{anchor} in {linked.name}")
    return problems


@pytest.mark.parametrize("page", PAGES, ids=lambda p: str(p.relative_to(ROOT)))
def test_every_relative_link_and_anchor_resolves(page):
    assert broken_links(page) == []


@pytest.mark.parametrize(
    "heading, slug",
    [  # as github.com renders these headings of this repository (the anchors its pages link to)
        ("A wrong calibration without GNSS: the field's circle in turns (honest19)",
         "a-wrong-calibration-without-gnss-the-fields-circle-in-turns-honest19"),
        ("First-start compile (`ahrsd warm-up`, the unit's ExecStartPre)",
         "first-start-compile-ahrsd-warm-up-the-units-execstartpre"),
        ("σ honesty in turns", "σ-honesty-in-turns"),
        ("ArduPilot (4.x, EKF3)", "ardupilot-4x-ekf3"),
        ("`ahrsd magcal`", "ahrsd-magcal"),
        ("Lost samples, measured", "lost-samples-measured"),
        ("Samples — `ahrsd.core.sample`", "samples--ahrsdcoresample"),
    ],
)
def test_the_slug_is_githubs(heading, slug):
    assert github_slug(heading) == slug


def test_a_broken_link_and_a_broken_anchor_are_found(tmp_path):
    """The checker itself: a page with a good link, a missing file, a missing anchor, a repeated heading's second
    anchor, and links inside code that must not count."""
    (tmp_path / "other.md").write_text("# Other\n\n## Part\n\n## Part\n", encoding="utf-8")
    page = tmp_path / "page.md"
    page.write_text(
        "# Page\n\n"
        "[good](other.md#part) and [second](other.md#part-1) and [self](#page)\n"
        "[gone](missing.md) and [no anchor](other.md#nowhere) and [third](other.md#part-2)\n"
        "`[in a span](missing-too.md)`\n\n"
        "```\n[in a fence](missing-three.md)\n```\n",
        encoding="utf-8",
    )
    assert broken_links(page) == [
        "page.md:4: missing.md: no such file",
        "page.md:4: other.md#nowhere: no heading gives #nowhere in other.md",
        "page.md:4: other.md#part-2: no heading gives #part-2 in other.md",
    ]
