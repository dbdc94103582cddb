"""``tools/gen_results.py``: docs/results.md and bench/results/INDEX.md are current, and the check
fails, with a message saying what to do, on every kind of drift (no benchmark is re-run)."""

from __future__ import annotations

import functools
import importlib.util
import json
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
TOOL = ROOT / "tools" / "gen_results.py"


def _gen(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, str(TOOL), *args], capture_output=True, text=True, timeout=120)


@functools.cache
def _module():
    """tools/gen_results.py as a module (a script folder, not a package: loaded by path)."""
    spec = importlib.util.spec_from_file_location("gen_results", TOOL)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses look their module up while the class is built
    spec.loader.exec_module(module)
    return module


def test_results_pages_are_current() -> None:
    """Every file of bench/results is indexed, every figure path resolves, both pages are current."""
    proc = _gen("--check")
    assert proc.returncode == 0, proc.stderr


def test_every_shown_number_comes_from_its_json() -> None:
    """Spot checks of the real pages against the JSON the benchmark wrote."""
    page = (ROOT / "docs" / "results.md").read_text(encoding="utf-8")
    ci = json.loads((ROOT / "bench" / "results" / "control_independent.json").read_text(encoding="utf-8"))
    goal = ci["summary"]["gap"]["goal"]
    assert f"| gap-corrected design: goal | {goal * 100:.1f} % |" in page
    latency = json.loads((ROOT / "bench" / "results" / "control_latency_600s_events.json").read_text())
    assert f"| missed | {latency['missed_samples']} |" in page
    index = (ROOT / "bench" / "results" / "INDEX.md").read_text(encoding="utf-8")
    listed = sorted(p.name for p in (ROOT / "bench" / "results").iterdir()
                    if p.name not in ("index.yaml", "INDEX.md") and not p.name.startswith("."))
    for name in listed:
        assert f"[{name}" in index, name


# ----------------------------------------------------------------------------- a small tree

INDEX_YAML = """\
areas:
  - {key: sim, title: Simulation}
results:
  - file: speed.json
    area: sim
    status: current
    title: Speed
    measures: How fast the thing runs.
    command: .venv/bin/python -m bench.bench_speed --runs 3
    supports: the thing runs at 90.3 % of the bound.
    docs: [docs/page.md#the-speed-section]
    figures:
      - {label: share of the bound, path: summary.share, fmt: .1%}
      - {label: wall time per run, path: "runs[*].wall_s", fmt: .1f, unit: s}
      - {label: runs ok, path: "runs[*].ok", reduce: count_true}
      - {label: fast run, path: "runs[name=fast].wall_s", fmt: .2f, unit: s}
    recorded:
      - {label: commit, path: meta.commit}
  - file: speed.md
    of: speed.json
  - file: speed_before.json
    area: sim
    status: history
    command: .venv/bin/python -m bench.bench_speed --runs 3 --out bench/results/speed_before.json
    note: the code of commit 1234abc
    supports: before the fix the thing ran at half the speed.
    docs: [docs/page.md]
"""

SPEED = {"summary": {"share": 0.9026}, "meta": {"commit": "abc1234"},
         "runs": [{"name": "fast", "wall_s": 1.25, "ok": True}, {"name": "slow", "wall_s": 3.5, "ok": False}]}


def _tree(root: Path) -> Path:
    (root / "bench" / "results").mkdir(parents=True)
    (root / "docs").mkdir()
    (root / "bench" / "bench_speed.py").write_text("print('speed')\n", encoding="utf-8")
    (root / "docs" / "page.md").write_text("# Page\n\n## The speed section\n\ntext\n", encoding="utf-8")
    (root / "bench" / "results" / "index.yaml").write_text(INDEX_YAML, encoding="utf-8")
    (root / "bench" / "results" / "speed.json").write_text(json.dumps(SPEED), encoding="utf-8")
    (root / "bench" / "results" / "speed.md").write_text("| run | wall |\n", encoding="utf-8")
    (root / "bench" / "results" / "speed_before.json").write_text("{}", encoding="utf-8")
    proc = _gen("--root", str(root))
    assert proc.returncode == 0, proc.stderr
    return root


def test_pages_hold_the_json_values(tmp_path: Path) -> None:
    root = _tree(tmp_path)
    page = (root / "docs" / "results.md").read_text(encoding="utf-8")
    assert "| share of the bound | 90.3 % |" in page
    assert "| wall time per run | 1.2–3.5 s |" in page
    assert "| runs ok | 1 of 2 |" in page
    assert "| fast run | 1.25 s |" in page
    assert "- **Run:** commit abc1234" in page
    assert "- **Re-make:** `.venv/bin/python -m bench.bench_speed --runs 3`" in page
    assert "[docs/page.md § The speed section](page.md#the-speed-section)" in page
    assert "[bench/results/speed.md](../bench/results/speed.md)" in page
    assert "speed_before" not in page  # history is listed in INDEX.md, not shown with figures
    index = (root / "bench" / "results" / "INDEX.md").read_text(encoding="utf-8")
    assert "| [speed_before.json](speed_before.json) | history | Simulation | " \
           "`.venv/bin/python -m bench.bench_speed --runs 3 --out bench/results/speed_before.json` " \
           "(the code of commit 1234abc) | before the fix the thing ran at half the speed. |" in index
    assert "| [speed.md](speed.md) | current | Simulation | " \
           "`.venv/bin/python -m bench.bench_speed --runs 3` | see [speed.json](speed.json) |" in index
    assert _gen("--check", "--root", str(root)).returncode == 0


def test_a_new_result_file_without_an_entry_fails(tmp_path: Path) -> None:
    root = _tree(tmp_path)
    (root / "bench" / "results" / "speed_after.json").write_text("{}", encoding="utf-8")
    proc = _gen("--check", "--root", str(root))
    assert proc.returncode == 1
    assert proc.stderr.strip() == ("gen_results: bench/results/speed_after.json is not in bench/results/"
                                   "index.yaml: add an entry (command, supports, status)")


def test_an_entry_whose_file_is_gone_fails(tmp_path: Path) -> None:
    root = _tree(tmp_path)
    (root / "bench" / "results" / "speed_before.json").unlink()
    proc = _gen("--check", "--root", str(root))
    assert proc.returncode == 1
    assert "bench/results/index.yaml names speed_before.json, which is not in bench/results: " \
           "remove its entry or restore the file" in proc.stderr


def test_a_figure_path_that_does_not_resolve_fails(tmp_path: Path) -> None:
    root = _tree(tmp_path)
    data = dict(SPEED, summary={"fraction": 0.9})  # the benchmark renamed its key
    (root / "bench" / "results" / "speed.json").write_text(json.dumps(data), encoding="utf-8")
    proc = _gen("--check", "--root", str(root))
    assert proc.returncode == 1
    assert "speed.json, figures[0] ('share of the bound'): path 'summary.share' does not resolve in " \
           "speed.json: no key 'share' after 'summary' (keys: fraction): fix the path" in proc.stderr


def test_a_rerun_benchmark_makes_the_page_stale(tmp_path: Path) -> None:
    root = _tree(tmp_path)
    data = dict(SPEED, summary={"share": 0.95})
    (root / "bench" / "results" / "speed.json").write_text(json.dumps(data), encoding="utf-8")
    proc = _gen("--check", "--root", str(root))
    assert proc.returncode == 1
    assert proc.stderr.strip() == ("gen_results: docs/results.md is stale: run `python tools/gen_results.py` "
                                   "and commit it")
    assert _gen("--root", str(root)).returncode == 0
    assert "| share of the bound | 95.0 % |" in (root / "docs" / "results.md").read_text(encoding="utf-8")


def test_stale_links_and_commands_fail(tmp_path: Path) -> None:
    root = _tree(tmp_path)
    (root / "docs" / "page.md").write_text("# Page\n\n## Renamed\n", encoding="utf-8")
    (root / "bench" / "bench_speed.py").rename(root / "bench" / "bench_fast.py")
    proc = _gen("--check", "--root", str(root))
    assert proc.returncode == 1
    lines = proc.stderr.splitlines()
    assert "gen_results: bench/results/index.yaml: speed.json: docs names docs/page.md#the-speed-section, " \
           "but docs/page.md has no heading with that anchor: fix the link" in lines
    assert "gen_results: bench/results/index.yaml: speed.json: the command names bench/bench_speed.py, " \
           "which does not exist: update the command" in lines


def test_malformed_entries_are_named(tmp_path: Path) -> None:
    root = _tree(tmp_path)
    text = INDEX_YAML.replace("    status: history\n", "    status: old\n").replace(
        "  - file: speed.md\n    of: speed.json\n", "  - file: speed.md\n    of: speed.jsn\n")
    (root / "bench" / "results" / "index.yaml").write_text(text, encoding="utf-8")
    proc = _gen("--check", "--root", str(root))
    assert proc.returncode == 1
    assert "speed_before.json: status 'old' is not one of current, superseded, history" in proc.stderr
    assert "speed.md: 'of: speed.jsn' names no entry: give an indexed file" in proc.stderr
    (root / "bench" / "results" / "index.yaml").write_text("areas: [\n", encoding="utf-8")
    proc = _gen("--check", "--root", str(root))
    assert proc.returncode == 1
    assert proc.stderr.startswith("gen_results: bench/results/index.yaml line ")
    assert "Traceback" not in proc.stderr


# ----------------------------------------------------------------------------- paths and formats

DATA = {"a": {"b": [1, 2, 3]}, "rows": [{"k": 50.0, "v": 0.1}, {"k": 30.0, "v": 0.2}, {"k": None, "v": 0.3}],
        "odd": {"0.2": 4, "x, y": 5}}


@pytest.mark.parametrize(("path", "values", "many"), [
    ("a.b[1]", [2], False),
    ("a.b[-1]", [3], False),
    ("a.b[*]", [1, 2, 3], True),
    ("rows[k=50].v", [0.1], True),
    ("rows[k=null].v", [0.3], True),
    ('odd["0.2"]', [4], False),
    ('odd["x, y"]', [5], False),
    ("rows[k=10].v", [], True),
])
def test_resolve(path: str, values: list, many: bool) -> None:
    assert _module().resolve(DATA, path) == (values, many)


@pytest.mark.parametrize(("path", "message"), [
    ("a.c", "no key 'c' after 'a' (keys: b)"),
    ("a.b[3]", "no element [3] after 'a.b' (a list of 3)"),
    ("a[0]", "no element [0] after 'a' (not a list)"),
])
def test_resolve_says_what_is_wrong(path: str, message: str) -> None:
    with pytest.raises(ValueError, match=message.replace("[", r"\[").replace("(", r"\(").replace(")", r"\)")):
        _module().resolve(DATA, path)


@pytest.mark.parametrize(("values", "many", "fig", "text"), [
    ([0.9026], False, {"fmt": ".1%"}, "90.3 %"),
    ([292970], False, {"fmt": ","}, "292 970"),
    ([0.0013, 0.0053], True, {"fmt": ".2%"}, "0.13–0.53 %"),
    ([-0.0219, -0.0032], True, {"fmt": ".2%"}, "-2.19 … -0.32 %"),
    ([0.203, 0.884], True, {"fmt": ".1%", "reduce": "list", "sep": " → "}, "20.3 → 88.4 %"),
    ([1.0, 2.0, 4.0], True, {"reduce": "median", "unit": "s"}, "2 s"),
    ([0.0005], False, {"scale": 1000, "fmt": ".1f", "unit": "ms"}, "0.5 ms"),
    ([True, False, True], True, {"reduce": "count_true"}, "2 of 3"),
    (["32d69c0"], False, {}, "32d69c0"),
    ([None], False, {}, "—"),
    ([], True, {"reduce": "count"}, "0"),
])
def test_render_figure(values: list, many: bool, fig: dict, text: str) -> None:
    assert _module().render_figure(values, many, fig) == text


def test_slug_matches_github_anchors() -> None:
    slug = _module().slug
    assert slug("Record → play → record (issue 34)") == "record--play--record-issue-34"
    assert slug("Controllers (`aeropend_control`: [docs/control.md](docs/control.md))") == \
        "controllers-aeropend_control-docscontrolmd"
