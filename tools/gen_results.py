#!/usr/bin/env python3
"""Write ``docs/results.md`` and ``bench/results/INDEX.md`` from ``bench/results/index.yaml``.

``bench/results/index.yaml`` is the one home of what each file in ``bench/results/`` is: the
command that makes it, the figure or claim it supports, where that claim is written, and its
status (``current``, ``superseded``, ``history``). For the current JSON results it also names
the figures to show, as paths into the JSON, so every number in ``docs/results.md`` is read from
the file the benchmark wrote and none is typed by hand. ``test/test_results_docs.py`` runs
``--check``, so the generated pages cannot go stale.

Usage: ``python tools/gen_results.py [--check] [--root DIR]``

* without ``--check``: validate the index and write both pages;
* ``--check``: write nothing; exit 1 when a page differs from what would be written, a file in
  ``bench/results/`` has no entry, an entry names a file that does not exist, a figure's JSON
  path does not resolve, or an entry is malformed. Every problem is one line on stderr saying
  what to do.

Plain Python and PyYAML (no aeropend import).

The index (``bench/results/index.yaml``)
----------------------------------------
``areas``: list of ``{key, title}``, the sections of ``docs/results.md`` in order.
``results``: one entry per file or folder directly in ``bench/results/``:

``file``
    name inside ``bench/results/`` (a folder without a trailing slash).
``of``
    the result file this one belongs to (a Markdown table, a plot, a part of the run, a folder
    of report files). ``area``, ``status``, ``command``, ``supports`` and ``docs`` default to
    that entry's (or its own ``of``'s); the file is linked from the result it belongs to in
    ``docs/results.md``.
``area``, ``status``
    a key of ``areas``; ``current`` (the figure the docs quote now), ``superseded`` (an earlier
    run of the same measurement, replaced by a newer file) or ``history`` (evidence of an
    investigation: a run before a fix, a candidate tried and rejected, a part merged elsewhere).
``command``
    the command that makes the file, run from the repository root (scripts named in it, and the
    modules it runs with ``python -m bench.x``, must exist).
``note``
    optional: how the command was run when that is not all in it (the code of another commit, a
    modified tree, runs merged by hand); goes with the command it is given with.
``supports``
    the figure or claim it supports (one sentence).
``docs``
    pages that discuss it (``path`` or ``path#anchor``, relative to the repository; must exist).
``title``, ``measures``
    current results only: heading and what was measured, for ``docs/results.md``.
``figures``
    current JSON results (at least one): list of ``{label, path}`` with optional ``fmt``,
    ``unit``, ``scale``, ``reduce`` and ``from``; see :func:`render_figure`.
``recorded``
    optional, same form as ``figures``: the run's context the JSON records (commit, date, load).

Figure paths
------------
Dotted keys with brackets, e.g. ``summary.gap.goal``, ``bound_s["0.2"]``, ``runs[0].p95_ms``,
``runs[*].p95_ms`` (every element), ``cases[case=aeroshield].seconds`` (elements whose field
equals the value; numbers compare numerically, ``null``/``true``/``false`` as JSON). ``[*]`` and
``[k=v]`` make the figure a list of values, shown as their range unless ``reduce`` says
otherwise (``range``, ``list``, ``min``, ``max``, ``median``, ``sum``, ``count``,
``count_true``). ``path`` may also be a list of paths (their values together). ``from`` (a file
name or a list of them) reads the path(s) in other indexed JSON files instead of the entry's
own, the values of all of them together.
"""

from __future__ import annotations

import argparse
import itertools
import json
import os
import re
import statistics
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

ROOT = Path(__file__).resolve().parents[1]
RESULTS = Path("bench/results")
INDEX = RESULTS / "index.yaml"
INDEX_MD = RESULTS / "INDEX.md"
RESULTS_MD = Path("docs/results.md")
OWN_FILES = (INDEX, INDEX_MD)  # the index and its page: not results, not listed
STATUSES = ("current", "superseded", "history")
ENTRY_KEYS = {"file", "of", "area", "status", "command", "note", "supports", "docs", "title", "measures",
              "figures", "recorded"}
FIGURE_KEYS = {"label", "path", "fmt", "unit", "scale", "reduce", "sep", "from"}
INHERITED = ("area", "status", "command", "supports", "docs")
REDUCERS = ("range", "list", "min", "max", "median", "sum", "count", "count_true")
SCRIPT = re.compile(r"^(?:bench|tools|scripts)/\S+\.(?:py|sh)$")
MODULE = re.compile(r"^(?:bench|tools)(?:\.\w+)+$")
REGENERATE = "python tools/gen_results.py"


class IndexFileError(Exception):
    """A problem with ``index.yaml`` or the files it names; the message is one line."""


# ----------------------------------------------------------------------------- JSON paths

_SEGMENT = re.compile(r"\.?([^.\[\]]+)|\[([^\]]*)\]")


def parse_path(path: str) -> list[tuple[str, Any]]:
    """Split a figure path into ``(kind, argument)`` segments.

    Parameters
    ----------
    path : str
        e.g. ``summary.gap.goal``, ``runs[*].p95_ms``, ``cases[case=aeroshield].seconds``,
        ``bound_s["0.2"]``.

    Returns
    -------
    list of (str, object)
        kinds ``key`` (str), ``index`` (int), ``all`` (None), ``match`` ((field, text)).

    Raises
    ------
    ValueError
        the path is empty or has a bracket that is none of ``[n]``, ``[*]``, ``["key"]``,
        ``[field=value]``.
    """
    segments: list[tuple[str, Any]] = []
    pos = 0
    while pos < len(path):
        m = _SEGMENT.match(path, pos)
        if m is None or m.end() == pos:
            raise ValueError(f"cannot read {path[pos:]!r}")
        if m.group(1) is not None:
            segments.append(("key", m.group(1).strip()))
        else:
            inner = m.group(2).strip()
            if inner == "*":
                segments.append(("all", None))
            elif re.fullmatch(r"-?\d+", inner):
                segments.append(("index", int(inner)))
            elif len(inner) >= 2 and inner[0] in "\"'" and inner[-1] == inner[0]:
                segments.append(("key", inner[1:-1]))
            elif "=" in inner:
                name, value = inner.split("=", 1)
                segments.append(("match", (name.strip(), value.strip().strip("\"'"))))
            else:
                raise ValueError(f"bracket [{inner}] is none of [n], [*], [\"key\"], [field=value]")
        pos = m.end()
    if not segments:
        raise ValueError("empty path")
    return segments


def _equals(value: Any, text: str) -> bool:
    if isinstance(value, bool) or value is None:
        return json.dumps(value) == text.lower()
    if isinstance(value, (int, float)):
        try:
            return float(text) == float(value)
        except ValueError:
            return False
    return str(value) == text


def _keys_hint(node: Any) -> str:
    if isinstance(node, dict):
        keys = list(node)
        more = f", ... ({len(keys)} keys)" if len(keys) > 12 else ""
        return f" (keys: {', '.join(map(str, keys[:12]))}{more})"
    return f" (a {type(node).__name__})"


def resolve(data: Any, path: str) -> tuple[list[Any], bool]:
    """Values at ``path`` in parsed JSON ``data``.

    Returns
    -------
    values : list
        one value, or every value a ``[*]`` / ``[field=value]`` selected (possibly none).
    many : bool
        the path holds a ``[*]`` or ``[field=value]`` (the values are a set, not one figure).

    Raises
    ------
    ValueError
        a key, index or selection does not exist; the message says where and what is there.
    """
    nodes, many, done = [data], False, ""
    for kind, arg in parse_path(path):
        out: list[Any] = []
        for node in nodes:
            if kind == "key":
                if not isinstance(node, dict) or arg not in node:
                    raise ValueError(f"no key {arg!r} after {done or 'the top'!r}{_keys_hint(node)}")
                out.append(node[arg])
            elif kind == "index":
                if not isinstance(node, list) or not -len(node) <= arg < len(node):
                    size = f"a list of {len(node)}" if isinstance(node, list) else "not a list"
                    raise ValueError(f"no element [{arg}] after {done!r} ({size})")
                out.append(node[arg])
            elif kind == "all":
                if not isinstance(node, (list, dict)):
                    raise ValueError(f"[*] after {done!r} is not a list or mapping")
                out.extend(node if isinstance(node, list) else node.values())
            else:
                name, text = arg
                items = node if isinstance(node, list) else [node]
                out.extend(e for e in items if isinstance(e, dict) and _equals(e.get(name), text))
        many = many or kind in ("all", "match")
        done += f"[{arg}]" if kind == "index" else ("[*]" if kind == "all" else (
            f"[{arg[0]}={arg[1]}]" if kind == "match" else (f".{arg}" if done else arg)))
        nodes = out
        if not nodes and kind in ("key", "index"):
            raise ValueError(f"{done!r} selects nothing")
        if not nodes:
            break
    return nodes, many


# ----------------------------------------------------------------------------- formatting

def _number(value: float, fmt: str) -> tuple[str, str]:
    """(text, suffix) of one number: ``fmt`` is a format spec; ``.1%`` gives ``90.3`` + `` %``
    (``#.2g%``: two significant digits in percent)."""
    if fmt.endswith("%"):
        spec = fmt[:-1] if fmt[-2:-1] in ("e", "f", "g") else fmt[:-1] + "f"
        return format(value * 100.0, spec), " %"
    return format(value, fmt).replace(",", " "), ""


def render_figure(values: list[Any], many: bool, fig: dict) -> str:
    """Text of one figure from its values.

    Parameters
    ----------
    values : list
        what :func:`resolve` returned (over every ``from`` file).
    many : bool
        the values are a set (reduce them) rather than one value.
    fig : dict
        ``fmt`` (format spec, default ``g``; ``,`` groups thousands with spaces; a spec ending
        in ``%`` shows a fraction in percent, ``.1%`` → ``90.3 %``), ``unit`` (appended after a
        space), ``scale`` (multiplies numbers first, e.g. 1000 for s → ms), ``reduce`` (how a
        set is shown: ``range`` ``a–b`` (default; ``a … b`` when a is negative), ``list``
        ``a / b / c`` (``sep`` replaces `` / ``), ``min``, ``max``,
        ``median``, ``sum``, ``count``, ``count_true`` ``k of n``: how many are true).

    Returns
    -------
    str
        e.g. ``90.3 %``, ``0.13–0.53 %``, ``292 970``, ``32d69c0``; ``—`` for a JSON null.
    """
    fmt, scale, sep = str(fig.get("fmt", "g")), fig.get("scale", 1), str(fig.get("sep", " / "))
    unit = f" {fig['unit']}" if fig.get("unit") else ""
    reduce = fig.get("reduce", "range" if many else None)
    nums = [v for v in values if isinstance(v, (int, float)) and not isinstance(v, bool)]
    if reduce == "count":
        return str(len(values))
    if reduce == "count_true":
        return f"{sum(bool(v) for v in values)} of {len(values)}"
    if not values:
        return "0"
    if (reduce and len(nums) != len(values)) or not nums:
        return sep.join(_plain(v) for v in values) + (unit if values[0] is not None else "")
    nums = [v * scale for v in nums]
    if reduce in ("min", "max", "median", "sum"):
        nums = [{"min": min, "max": max, "median": statistics.median, "sum": sum}[reduce](nums)]
    texts = [_number(v, fmt) for v in nums]
    suffix = texts[0][1] + unit
    if reduce == "list":
        return sep.join(t for t, _ in texts) + suffix
    lo, hi = _number(min(nums), fmt)[0], _number(max(nums), fmt)[0]
    dash = " … " if min(nums) < 0 else "–"
    return (lo if lo == hi else f"{lo}{dash}{hi}") + suffix


def _plain(value: Any) -> str:
    if value is None:
        return "—"
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, list):
        return ", ".join(_plain(v) for v in value)
    return str(value)


# ----------------------------------------------------------------------------- the index

@dataclass
class Entry:
    """One file of ``bench/results`` as the index describes it (inherited fields filled in)."""

    file: str
    raw: dict
    area: str = ""
    status: str = ""
    command: str = ""
    note: str = ""
    supports: str = ""
    docs: list[str] = field(default_factory=list)
    of: str | None = None
    parts: list[str] = field(default_factory=list)
    figures: list[tuple[str, str]] = field(default_factory=list)  # (label, text)
    recorded: list[tuple[str, str]] = field(default_factory=list)


@dataclass
class Index:
    """The parsed index: areas in order, entries by file name, and the problems found."""

    areas: dict[str, str]
    entries: dict[str, Entry]
    problems: list[str]


def _listed(root: Path) -> list[str]:
    folder = root / RESULTS
    skip = {p.name for p in OWN_FILES}
    return sorted(p.name for p in folder.iterdir() if not p.name.startswith(".") and p.name not in skip)


def _load_yaml(root: Path) -> dict:
    path = root / INDEX
    if not path.is_file():
        raise IndexFileError(f"{INDEX} is missing: it lists every file of {RESULTS} "
                             f"(see {REGENERATE} --help)")
    try:
        data = yaml.safe_load(path.read_text(encoding="utf-8"))
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f" line {mark.line + 1}" if mark is not None else ""
        problem = getattr(exc, "problem", exc)
        raise IndexFileError(f"{INDEX}{where}: not valid YAML ({problem}): fix it") from None
    if not isinstance(data, dict) or not isinstance(data.get("areas"), list) \
            or not isinstance(data.get("results"), list):
        raise IndexFileError(f"{INDEX}: expected a mapping with lists 'areas' and 'results'")
    return data


def load_index(root: Path) -> Index:
    """Read and validate ``index.yaml`` against the folder; problems are collected, not raised.

    Raises
    ------
    IndexFileError
        the index is missing or not YAML of the expected shape (nothing else can be checked).
    """
    data = _load_yaml(root)
    problems: list[str] = []
    areas: dict[str, str] = {}
    for i, area in enumerate(data["areas"]):
        if not isinstance(area, dict) or set(area) != {"key", "title"}:
            problems.append(f"{INDEX}: areas[{i}] must be {{key, title}}")
        else:
            areas[str(area["key"])] = str(area["title"])
    entries: dict[str, Entry] = {}
    for i, raw in enumerate(data["results"]):
        if not isinstance(raw, dict) or not isinstance(raw.get("file"), str):
            problems.append(f"{INDEX}: results[{i}] has no 'file': give the file name in {RESULTS}")
            continue
        name = raw["file"].rstrip("/")
        if name in entries:
            problems.append(f"{INDEX}: {name} has two entries: merge them into one")
            continue
        unknown = set(raw) - ENTRY_KEYS
        if unknown:
            problems.append(f"{INDEX}: {name}: unknown field(s) {', '.join(sorted(unknown))} "
                            f"(allowed: {', '.join(sorted(ENTRY_KEYS))})")
        entries[name] = Entry(file=name, raw=raw, of=raw.get("of"))
    _inherit(entries, problems)
    _check_entries(root, areas, entries, problems)
    listed = _listed(root)
    for name in listed:
        if name not in entries:
            problems.append(f"{RESULTS}/{name} is not in {INDEX}: add an entry (command, supports, status)")
    for name in entries:
        if name not in listed:
            problems.append(f"{INDEX} names {name}, which is not in {RESULTS}: "
                            "remove its entry or restore the file")
    return Index(areas, entries, problems)


def _inherit(entries: dict[str, Entry], problems: list[str]) -> None:
    """Fill each entry's fields from its own raw values, else from the nearest ``of`` ancestor's."""
    for e in entries.values():
        chain, node = [e], e
        while node.of is not None:
            parent = entries.get(node.of)
            if parent is None:
                problems.append(f"{INDEX}: {node.file}: 'of: {node.of}' names no entry: give an indexed file")
                break
            if parent in chain:
                problems.append(f"{INDEX}: {e.file}: its 'of' chain comes back to {parent.file}: "
                                "break the loop")
                break
            chain.append(parent)
            node = parent
        root = chain[-1]
        if root is not e and node.of is None:
            root.parts.append(e.file)
        for key in INHERITED:
            value = next((c.raw[key] for c in chain if c.raw.get(key) is not None), None)
            if value is None:
                hint = "" if e.of else " (or 'of: FILE' to take it from the result it belongs to)"
                problems.append(f"{INDEX}: {e.file}: missing '{key}'{hint}")
                value = [] if key == "docs" else ""
            setattr(e, key, value)
        source = next((c for c in chain if c.raw.get("command") is not None), None)
        e.note = " ".join(str(source.raw.get("note") or "").split()) if source is not None else ""


def _scripts(command: str) -> list[str]:
    """Repository files a command runs: script paths (``bench/x.py``, ``tools/x.py``,
    ``scripts/x.sh``) and modules run with ``-m`` (``-m bench.repro.x`` -> ``bench/repro/x.py``)."""
    tokens = command.split()
    out = [t for t in tokens if SCRIPT.match(t)]
    for flag, module in itertools.pairwise(tokens):
        if flag == "-m" and MODULE.match(module):
            out.append(module.replace(".", "/") + ".py")
    return out


def _check_entries(root: Path, areas: dict[str, str], entries: dict[str, Entry],
                   problems: list[str]) -> None:
    for e in entries.values():
        where = f"{INDEX}: {e.file}"
        if e.area and e.area not in areas:
            problems.append(f"{where}: area '{e.area}' is not one of {', '.join(areas)}")
        if e.status and e.status not in STATUSES:
            problems.append(f"{where}: status '{e.status}' is not one of {', '.join(STATUSES)}")
        if not isinstance(e.docs, list):
            problems.append(f"{where}: 'docs' must be a list of paths")
            e.docs = []
        for doc in e.docs:
            path, _, anchor = str(doc).partition("#")
            if not (root / path).exists():
                problems.append(f"{where}: docs names {doc}, which does not exist: fix the path")
            elif anchor and path.endswith(".md") and anchor not in headings(root / path):
                problems.append(f"{where}: docs names {doc}, but {path} has no heading with that "
                                "anchor: fix the link")
        for script in _scripts(str(e.command)):
            if not (root / script).exists():
                problems.append(f"{where}: the command names {script}, which does not exist: "
                                "update the command")
        standalone = e.of is None and e.status == "current"
        if standalone:
            for key in ("title", "measures"):
                if not e.raw.get(key):
                    problems.append(f"{where}: a current result needs '{key}' (shown in {RESULTS_MD})")
        if e.raw.get("figures") and not standalone:
            problems.append(f"{where}: only a current result with no 'of' shows figures: "
                            "remove them or make it current")
        if standalone and e.file.endswith(".json") and not e.raw.get("figures"):
            problems.append(f"{where}: a current JSON result needs 'figures' (label, path) to show "
                            f"in {RESULTS_MD}")


def slug(heading: str) -> str:
    """GitHub's anchor of a Markdown heading: link text kept, punctuation dropped, spaces to ``-``."""
    text = re.sub(r"\[([^\]]*)\]\([^)]*\)", r"\1", heading).strip().lower()
    return re.sub(r"[^\w\- ]", "", text).replace(" ", "-")


def headings(path: Path) -> dict[str, str]:
    """Anchor → plain text of every heading of Markdown file ``path`` (code blocks skipped;
    a repeated anchor gets ``-1``, ``-2``, ... as on GitHub)."""
    anchors: dict[str, str] = {}
    counts: dict[str, int] = {}
    fenced = False
    for line in path.read_text(encoding="utf-8").splitlines():
        if line.startswith("```"):
            fenced = not fenced
        elif not fenced and re.match(r"#{1,6} ", line):
            text = line.lstrip("#").strip()
            base = slug(text)
            n = counts.get(base, 0)
            plain = re.sub(r"\[([^\]]*)\]\([^)]*\)", r"\1", text).replace("`", "")
            anchors[base if n == 0 else f"{base}-{n}"] = plain
            counts[base] = n + 1
    return anchors


# ----------------------------------------------------------------------------- figures

class _Cache:
    def __init__(self, root: Path) -> None:
        self.root, self.data = root, {}

    def get(self, name: str) -> Any:
        if name not in self.data:
            path = self.root / RESULTS / name
            try:
                self.data[name] = json.loads(path.read_text(encoding="utf-8"))
            except (OSError, ValueError) as exc:
                raise ValueError(f"cannot read {RESULTS}/{name} as JSON ({exc})") from None
        return self.data[name]


def _figure(cache: _Cache, index: Index, e: Entry, kind: str, i: int, fig: Any) -> tuple[str, str]:
    where = f"{INDEX}: {e.file}, {kind}[{i}]"
    if not isinstance(fig, dict) or "label" not in fig or "path" not in fig:
        raise ValueError(f"{where} needs 'label' and 'path'")
    unknown = set(fig) - FIGURE_KEYS
    if unknown:
        raise ValueError(f"{where}: unknown field(s) {', '.join(sorted(unknown))} "
                         f"(allowed: {', '.join(sorted(FIGURE_KEYS))})")
    if fig.get("reduce") not in (None, *REDUCERS):
        raise ValueError(f"{where}: reduce '{fig['reduce']}' is not one of {', '.join(REDUCERS)}")
    sources = fig.get("from", e.file)
    sources = [sources] if isinstance(sources, str) else list(sources)
    paths = fig["path"] if isinstance(fig["path"], list) else [fig["path"]]
    values: list[Any] = []
    many = len(sources) > 1 or len(paths) > 1
    for src in sources:
        if src not in index.entries:
            raise ValueError(f"{where} ('{fig['label']}'): from {src}, which is not in {INDEX}")
        for path in paths:
            try:
                got, several = resolve(cache.get(src), str(path))
            except ValueError as exc:
                raise ValueError(f"{where} ('{fig['label']}'): path '{path}' does not resolve in "
                                 f"{src}: {exc}: fix the path") from None
            values += got
            many = many or several
    if not values and fig.get("reduce") not in ("count", "count_true", "sum"):
        raise ValueError(f"{where} ('{fig['label']}'): path {fig['path']!r} selects nothing in "
                         f"{', '.join(sources)}: fix the path (or count with reduce: count)")
    try:
        return str(fig["label"]), render_figure(values, many, fig)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{where} ('{fig['label']}'): cannot format {values[:3]} with "
                         f"fmt '{fig.get('fmt', 'g')}' ({exc})") from None


def read_figures(root: Path, index: Index) -> None:
    """Fill every entry's ``figures`` and ``recorded`` texts; problems go to ``index.problems``."""
    cache = _Cache(root)
    for e in index.entries.values():
        for kind in ("figures", "recorded"):
            figs = e.raw.get(kind) or []
            if not isinstance(figs, list):
                index.problems.append(f"{INDEX}: {e.file}: '{kind}' must be a list")
                continue
            out = []
            for i, fig in enumerate(figs):
                try:
                    out.append(_figure(cache, index, e, kind, i, fig))
                except ValueError as exc:
                    index.problems.append(str(exc))
            setattr(e, kind, out)


# ----------------------------------------------------------------------------- pages

def _cell(text: Any) -> str:
    return " ".join(str(text).split()).replace("|", "\\|")


def _link(target: str, base: Path, root: Path) -> str:
    """Markdown link from folder ``base`` to repository path ``target`` (may hold ``#anchor``);
    the text is the path and, for an anchor, the heading it names."""
    path, _, anchor = str(target).partition("#")
    href = Path(os.path.relpath(path, base)).as_posix() + (f"#{anchor}" if anchor else "")
    text = path
    if anchor:
        title = headings(root / path).get(anchor, anchor) if path.endswith(".md") else anchor
        text += " § " + (title if len(title) <= 60 else title[:59].rstrip(" ,;:(") + "…")
    return f"[{_cell(text)}]({href})"


def _command(e: Entry) -> str:
    code = "`" + _cell(e.command).replace("`", "'") + "`"
    return f"{code} ({_cell(e.note)})" if e.note else code


INTRO = """\
What aeropend measured, and the command that measures it again. Every number below is read from
the JSON file named with it in `bench/results/` by `{regen}` (this page is generated: edit
`bench/results/index.yaml` or re-run a benchmark, then run that command; `test/test_results_docs.py`
fails when this page is stale). What every file in `bench/results/` is, current or kept as
evidence, is listed in [bench/results/INDEX.md](../bench/results/INDEX.md).

**How this machine affects the timings.** The benchmarks ran on a virtual machine with **2 CPU
cores shared with other engineers' tests and benchmarks**. A load average of 2 means both cores
were busy; many runs saw 4 to 14. Where the JSON records it, the run's load, commit and date are
given with each result. What depends on the load: wall-clock times, real-time factors, loop
latencies and missed deadlines (a whole-VM stall of 10 ms shows as a late command whatever the
code does), and the rates of real-time ROS processes. What does not: seeded results (effects
named, coefficient errors, NRMSE, closed-loop step metrics in lock-step, samples recorded), which
repeat bit for bit, and CPU-time figures (e.g. decoded frames per CPU second). Compare a timing
only with one taken at a similar load, or re-run the command on your machine.
"""


def results_md(root: Path, index: Index) -> str:
    """Text of ``docs/results.md``: the current results by area, figures from their JSON."""
    base = RESULTS_MD.parent
    current = [e for e in index.entries.values() if e.status == "current" and e.of is None]
    out = ["# Results", "", "<!-- Generated by tools/gen_results.py from bench/results/index.yaml and "
           "bench/results/*.json: do not edit; run `python tools/gen_results.py`. -->", "",
           INTRO.format(regen=REGENERATE)]
    used = [k for k in index.areas if any(e.area == k for e in current)]
    out += ["Areas: " + " · ".join(f"[{index.areas[k]}](#{slug(index.areas[k])})" for k in used), ""]
    for key in used:
        out += [f"## {index.areas[key]}", ""]
        for e in sorted((e for e in current if e.area == key), key=lambda e: _order(index, e)):
            out += _result_section(root, e, base)
    kept = [e for e in index.entries.values() if e.status != "current"]
    out += ["## Earlier runs and investigations", "",
            f"{len(kept)} more files in `bench/results/` are earlier runs of a measurement above "
            "(`superseded`) or the evidence of an investigation (`history`: runs before a fix, "
            "candidates tried and rejected, parts merged into another file). The docs pages that "
            "tell those stories quote them; [bench/results/INDEX.md](../bench/results/INDEX.md) "
            "lists each with the command that made it and what it shows.", ""]
    return "\n".join(out).rstrip() + "\n"


def _order(index: Index, e: Entry) -> int:
    return list(index.entries).index(e.file)


def _result_section(root: Path, e: Entry, base: Path) -> list[str]:
    lines = [f"### {_cell(e.raw['title'])}", "", " ".join(str(e.raw["measures"]).split()), ""]
    if e.figures:
        lines += ["| figure | value |", "|---|---|"]
        lines += [f"| {_cell(label)} | {_cell(text)} |" for label, text in e.figures]
        lines.append("")
    lines.append(f"- **From:** {_link(str(RESULTS / e.file), base, root)}"
                 + (" with " + ", ".join(_link(str(RESULTS / p), base, root) for p in e.parts)
                    if e.parts else ""))
    if e.recorded:
        lines.append("- **Run:** " + "; ".join(f"{label} {text}" for label, text in e.recorded))
    lines.append(f"- **Re-make:** {_command(e)}")
    if e.docs:
        lines.append("- **Discussed in:** " + ", ".join(_link(d, base, root) for d in e.docs))
    return [*lines, ""]


def index_md(root: Path, index: Index) -> str:
    """Text of ``bench/results/INDEX.md``: every file, its command, what it supports, its status."""
    base = RESULTS
    out = ["# bench/results: what each file is", "",
           "<!-- Generated by tools/gen_results.py from bench/results/index.yaml: do not edit; edit "
           "index.yaml and run `python tools/gen_results.py`. -->", "",
           "Every file in this folder, the command that makes it, the figure or claim it supports and "
           "where that is written. Status: **current** (the figure the docs quote now; its numbers are "
           "in [docs/results.md](../../docs/results.md)), **superseded** (an earlier run of the same "
           "measurement, replaced by a newer file), **history** (evidence of an investigation: a run "
           "before a fix, a candidate tried and rejected, a part merged into another file). A file "
           "that belongs to another (its table, plot, parts or report folder) names it and shares its "
           "command. Commands run from the repository root after `./scripts/setup_env.sh`.", "",
           f"A new result file needs an entry in [index.yaml](index.yaml) (command, supports, status), "
           f"then `{REGENERATE}`; `test/test_results_docs.py` fails until it has one.", "",
           "| file | status | area | made by | supports | discussed in |", "|---|---|---|---|---|---|"]
    for name in sorted(index.entries):
        e = index.entries[name]
        label = name + ("/" if (root / RESULTS / name).is_dir() else "")
        supports = _cell(e.raw["supports"]) if "supports" in e.raw else f"see [{e.of}]({e.of})"
        if e.of and "supports" in e.raw:
            supports = f"(of [{e.of}]({e.of})) " + supports
        if (root / RESULTS / name).is_dir():
            held = sorted(p.relative_to(root / RESULTS / name).as_posix()
                          for p in (root / RESULTS / name).rglob("*") if p.is_file())
            supports += " Holds: " + ", ".join(f"`{h}`" for h in held) + "."
        docs = ", ".join(_link(d, base, root) for d in e.docs) or "—"
        out.append(f"| [{label}]({label}) | {e.status} | {index.areas.get(e.area, e.area)} | "
                   f"{_command(e)} | {supports} | {docs} |")
    return "\n".join(out) + "\n"


# ----------------------------------------------------------------------------- main

def build(root: Path) -> tuple[dict[Path, str], list[str]]:
    """The two pages' texts by path, and every problem of the index (empty when consistent)."""
    try:
        index = load_index(root)
    except IndexFileError as exc:
        return {}, [str(exc)]
    read_figures(root, index)
    if index.problems:
        return {}, index.problems
    return {RESULTS_MD: results_md(root, index), INDEX_MD: index_md(root, index)}, []


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n", 1)[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--check", action="store_true",
                    help="write nothing; exit 1 if a page is stale or the index is inconsistent")
    ap.add_argument("--root", type=Path, default=ROOT, help="repository root (default: this checkout)")
    args = ap.parse_args(argv)
    pages, problems = build(args.root)
    for line in problems:
        print(f"gen_results: {line}", file=sys.stderr)
    if problems:
        return 1
    stale = []
    for rel, text in pages.items():
        path = args.root / rel
        old = path.read_text(encoding="utf-8") if path.is_file() else None
        if old == text:
            continue
        if args.check:
            stale.append(f"gen_results: {rel} is {'missing' if old is None else 'stale'}: "
                         f"run `{REGENERATE}` and commit it")
        else:
            path.write_text(text, encoding="utf-8")
            print(f"wrote {rel}")
    for line in stale:
        print(line, file=sys.stderr)
    return 1 if stale else 0


if __name__ == "__main__":
    sys.exit(main())
