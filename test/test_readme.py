"""The README is a front door and the docs' links hold: README.md is short, starts with the two
set-up commands and carries no commit hash, issue number or path outside the repository; every
relative link of README.md and docs/**/*.md names an existing file and, into a Markdown file of
the repository, an existing heading (GitHub's anchor rules)."""

from __future__ import annotations

import functools
import re
import unicodedata
from pathlib import Path
from urllib.parse import unquote

import pytest

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
MAX_LINES = 250
FIRST_LINES = 30
COMMANDS = ("./scripts/run_main.sh", "./scripts/test.sh")

#: A commit hash as people paste it: 7-40 hex digits with at least one digit and one letter
#: (so neither a number nor a word such as "decade" counts).
_HASH = re.compile(r"(?<![\w/.-])(?=[0-9a-f]*[0-9])(?=[0-9a-f]*[a-f])[0-9a-f]{7,40}(?![\w/-])")
#: "issue 39", "issues 4 and 18", "#39" (an issue or pull request), not "#anchor" or "C#".
_ISSUE = re.compile(r"\bissues?\s+#?\d+|(?<![\w(/#.])#\d+\b", re.IGNORECASE)
#: inline links and images ``[text](target "title")``; the target may start on the next line.
_LINK = re.compile(r"!?\[(?:[^\]\[]|\[[^\]]*\])*\]\(\s*<?([^)\s>]+)>?(?:\s+\"[^\"]*\")?\s*\)")
_FENCE = re.compile(r"^(```|~~~)")


def _prose(text: str) -> str:
    """``text`` without its fenced code blocks (a link inside one is not a link)."""
    out, fenced = [], False
    for line in text.splitlines():
        if _FENCE.match(line):
            fenced = not fenced
            continue
        out.append("" if fenced else line)
    return "\n".join(out)


def github_slug(heading: str) -> str:
    """GitHub's anchor of a heading: the rendered text (link targets, backticks and emphasis
    markers dropped) lower-cased, every character that is not a letter, mark, number, ``_``,
    ``-`` or space removed, spaces turned into ``-`` (github-slugger's rule)."""
    text = re.sub(r"!?\[([^\]]*)\]\([^)]*\)", r"\1", heading.strip())
    text = re.sub(r"(\*\*|__|\*|`)", "", text).lower()
    kept = "".join(c for c in text if c in "-_ " or unicodedata.category(c)[0] in "LMN")
    return kept.replace(" ", "-")


@functools.cache
def anchors(path: Path) -> frozenset[str]:
    """Every heading anchor of Markdown file ``path`` (a repeated one gets ``-1``, ``-2``, ...)."""
    found: set[str] = set()
    counts: dict[str, int] = {}
    for line in _prose(path.read_text(encoding="utf-8")).splitlines():
        m = re.match(r"#{1,6}\s+(.*?)\s*#*\s*$", line)
        if not m:
            continue
        base = github_slug(m.group(1))
        n = counts.get(base, 0)
        found.add(base if n == 0 else f"{base}-{n}")
        counts[base] = n + 1
    found.update(re.findall(r"<a\s+(?:name|id)=\"([^\"]+)\"", path.read_text(encoding="utf-8")))
    return frozenset(found)


def link_problems(page: Path, root: Path = ROOT) -> list[str]:
    """One line per relative link of Markdown file ``page`` (inside repository ``root``) that does
    not resolve."""
    problems = []
    for target in _LINK.findall(_prose(page.read_text(encoding="utf-8"))):
        if re.match(r"[a-z][a-z0-9+.-]*:", target, re.IGNORECASE):  # http:, https:, mailto:
            continue
        path_part, _, anchor = target.partition("#")
        where = page.relative_to(root)
        dest = page if not path_part else (page.parent / unquote(path_part)).resolve()
        if not dest.exists():
            problems.append(f"{where}: link to {target!r}: no such file")
            continue
        if root not in dest.parents and dest != root:
            problems.append(f"{where}: link to {target!r} leaves the repository")
            continue
        if anchor and dest.suffix == ".md" and unquote(anchor) not in anchors(dest):
            problems.append(f"{where}: link to {target!r}: {dest.relative_to(root)} has no heading "
                            f"with that anchor")
    return problems


def _pages() -> list[Path]:
    return [README, *sorted((ROOT / "docs").rglob("*.md"))]


def test_readme_is_short_and_starts_with_the_two_commands() -> None:
    lines = README.read_text(encoding="utf-8").splitlines()
    assert len(lines) <= MAX_LINES, f"README.md has {len(lines)} lines, at most {MAX_LINES}"
    head = "\n".join(lines[:FIRST_LINES])
    for command in COMMANDS:
        assert command in head, f"{command} is not in the first {FIRST_LINES} lines of README.md"


def test_readme_has_no_commit_hash_issue_number_or_outside_path() -> None:
    text = README.read_text(encoding="utf-8")
    problems = [f"line {n}: commit hash {m.group(0)!r}"
                for n, line in enumerate(text.splitlines(), 1) for m in _HASH.finditer(line)]
    problems += [f"line {n}: issue number {m.group(0)!r}"
                 for n, line in enumerate(text.splitlines(), 1) for m in _ISSUE.finditer(line)]
    problems += [f"line {n}: path outside the repository ({line.strip()[:60]!r})"
                 for n, line in enumerate(text.splitlines(), 1) if "../shared" in line]
    assert not problems, "README.md:\n" + "\n".join(problems)


@pytest.mark.parametrize("page", _pages(), ids=lambda p: str(p.relative_to(ROOT)))
def test_every_relative_link_resolves(page: Path) -> None:
    problems = link_problems(page)
    assert not problems, "\n".join(problems)


@pytest.mark.parametrize(("heading", "anchor"), [
    ("Predicted held-out error, attainable shrink and session drift (`gap.drift`)",
     "predicted-held-out-error-attainable-shrink-and-session-drift-gapdrift"),
    ("Record → play → record (issue 34)", "record--play--record-issue-34"),
    ("The rig's sensor set: θ without θ̇ (issue 18)", "the-rigs-sensor-set-θ-without-θ̇-issue-18"),
    ("Three protocols (`bench/bench_ident_sensor_set.py`)", "three-protocols-benchbench_ident_sensor_setpy"),
    ("**Bold** and [a link](x.md) in a heading", "bold-and-a-link-in-a-heading"),
])
def test_github_slug(heading: str, anchor: str) -> None:
    assert github_slug(heading) == anchor


def test_the_checks_catch_what_they_should(tmp_path: Path) -> None:
    """The patterns flag a hash, an issue number and a broken anchor, and spare their look-alikes."""
    assert _HASH.search("merged at 8559cc8 today") and _HASH.search("commit `1a6dbc6`")
    assert not _HASH.search("9900 samples, 1234567 rows, a decade, docs/results/abc1234.png")
    assert _ISSUE.search("see issue 39") and _ISSUE.search("fixed in #12")
    assert not _ISSUE.search("[x](docs/gap.md#1-before) and C# code")
    page = tmp_path / "docs" / "p.md"
    page.parent.mkdir()
    page.write_text("# Title\n\n## Two words\n\n[ok](#two-words) [bad](#three) [gone](q.md)\n"
                    "```\n[in code](nowhere.md)\n```\n", encoding="utf-8")
    problems = link_problems(page, root=tmp_path)
    assert len(problems) == 2 and "'#three'" in problems[0] and "'q.md'" in problems[1], problems
