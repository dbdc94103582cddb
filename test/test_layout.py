"""``tools/check_layout.py``: the check itself, and the source tree passing it."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
TOOL = ROOT / "tools" / "check_layout.py"


def _run(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, str(TOOL), *args], capture_output=True, text=True,
                          timeout=120)


def _package(root: Path, name: str, modules: dict[str, str]) -> Path:
    pkg = root / name / name
    pkg.mkdir(parents=True)
    (pkg / "__init__.py").write_text('"""Fake package."""\n', encoding="utf-8")
    for mod, text in modules.items():
        path = pkg / f"{mod}.py"
        path.parent.mkdir(parents=True, exist_ok=True)
        if path.parent != pkg:
            (path.parent / "__init__.py").write_text("", encoding="utf-8")
        path.write_text(text, encoding="utf-8")
    return pkg


def test_clean_tree_passes(tmp_path: Path) -> None:
    _package(tmp_path, "fake", {"a": "from fake import b\n", "b": "X = 1\n",
                                "sub/c": "from fake.sub.d import Y\n", "sub/d": "Y = 2\n"})
    proc = _run("--root", str(tmp_path))
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "0 problem(s)" in proc.stdout


def test_lazy_import_cycle_fails(tmp_path: Path) -> None:
    _package(tmp_path, "fake", {
        "a": "from fake.b import g\n\ndef f():\n    return g()\n",
        "b": "def g():\n    from fake.a import f  # lazy: still a cycle\n    return f\n"})
    proc = _run("--root", str(tmp_path))
    assert proc.returncode == 1
    assert "import cycle between fake.a, fake.b" in proc.stdout
    assert "b.py:2" in proc.stdout


def test_relative_import_cycle_fails(tmp_path: Path) -> None:
    _package(tmp_path, "fake", {"sub/a": "from . import b\n", "sub/b": "from .a import X\n"})
    proc = _run("--root", str(tmp_path))
    assert proc.returncode == 1
    assert "import cycle between fake.sub.a, fake.sub.b" in proc.stdout


def test_long_function_fails(tmp_path: Path) -> None:
    body = "".join(f"    x{i} = {i}\n" for i in range(150))
    _package(tmp_path, "fake", {"a": f"def long():\n{body}    return 0\n\n\ndef short():\n    return 1\n"})
    proc = _run("--root", str(tmp_path))
    assert proc.returncode == 1
    assert "a.py:1: function fake.a.long has 152 lines (> 150)" in proc.stdout
    assert "short" not in proc.stdout


def test_too_many_modules_fails(tmp_path: Path) -> None:
    pkg = _package(tmp_path, "fake", {f"m{i}": "" for i in range(11)})
    proc = _run("--root", str(tmp_path))
    assert proc.returncode == 1
    assert f"{pkg / '__init__.py'}:1: package folder has 11 modules (> 10)" in proc.stdout
    (pkg / "m10.py").unlink()
    assert _run("--root", str(tmp_path)).returncode == 0


def test_source_tree_passes() -> None:
    """``src/``: no import cycle, no function over 150 lines, no package folder over 10 modules."""
    proc = _run()
    assert proc.returncode == 0, proc.stdout + proc.stderr


#: aeropend_ident's layering (docs/architecture.md): subpackage -> what it may import inside ident.
IDENT_LAYERS = {
    "cli": {"gap", "sindy", "greybox", "io", "pipeline", "errors"},
    "pipeline": {"greybox", "io", "errors"},
    "gap": {"sindy", "greybox", "io", "errors"},
    "sindy": {"io", "errors"},
    "greybox": {"io", "errors"},
    "nodes": {"io", "errors"},
    "io": {"errors"},
    "errors": set(),
}


def test_ident_layering() -> None:
    """Inside aeropend_ident every import follows the arrows of docs/architecture.md."""
    from tools import check_layout

    modules = check_layout._modules(ROOT / "src")
    wrong = []
    for name, path in modules.items():
        parts = name.split(".")
        if parts[0] != "aeropend_ident" or len(parts) < 2:
            continue
        for target, line in check_layout._imports(name, path, modules).items():
            tparts = target.split(".")
            if tparts[0] != "aeropend_ident" or len(tparts) < 2 or tparts[1] == parts[1]:
                continue
            if tparts[1] not in IDENT_LAYERS[parts[1]]:
                wrong.append(f"{path}:{line}: {name} imports {target}")
    assert not wrong, "\n".join(wrong)
