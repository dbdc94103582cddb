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
    body = "".join(f"    x{i} = {i}\n" for i in range(80))
    doc = '    """A docstring of\n    any length does not count."""\n'
    _package(tmp_path, "fake", {"a": f"def long():\n{body}    return 0\n\n\ndef short():\n{doc}{body[:-26]}"
                                     "    return 1\n"})
    proc = _run("--root", str(tmp_path))
    assert proc.returncode == 1
    assert "a.py:1: function fake.a.long has 82 lines of code (> 80)" in proc.stdout
    assert "short" not in proc.stdout  # 82 lines with its docstring, 80 of code


def test_a_table_may_be_long_when_it_says_so(tmp_path: Path) -> None:
    body = "".join(f"    x{i} = {i}\n" for i in range(90))
    _package(tmp_path, "fake", {"a": f"# a table: ninety settings\ndef settings():\n{body}    return 0\n",
                                "b": f"# settings, not a table mark\ndef settings():\n{body}    return 0\n"})
    proc = _run("--root", str(tmp_path))
    assert proc.returncode == 1 and "fake.b.settings" in proc.stdout and "fake.a" not in proc.stdout


def test_long_module_fails(tmp_path: Path) -> None:
    body = "".join(f"X{i} = {i}\n" for i in range(801))
    pkg = _package(tmp_path, "fake", {"big": body, "small": "Y = 1\n"})
    proc = _run("--root", str(tmp_path))
    assert proc.returncode == 1
    assert f"{pkg / 'big.py'}:1: module fake.big has 801 lines (> 800)" in proc.stdout
    assert "small" not in proc.stdout
    assert _run("--root", str(tmp_path), "--max-module-lines", "801").returncode == 0


def test_a_folder_holds_as_many_modules_as_its_concept_needs(tmp_path: Path) -> None:
    """The old cap of 10 modules per folder is gone: a folder is one concept, not a count."""
    _package(tmp_path, "fake", {f"m{i}": "X = 1\n" for i in range(14)})
    assert _run("--root", str(tmp_path)).returncode == 0


def test_source_tree_passes() -> None:
    """``src/``: no import cycle, no function over 80 lines of code (docstring excluded; a table that
    says so may be longer), no module over 800 lines, no arrow back up between packages."""
    proc = _run()
    assert proc.returncode == 0, proc.stdout + proc.stderr


def test_own_package_init_import_fails(tmp_path: Path) -> None:
    """A submodule importing a name from its own package's __init__ (which re-exports the API)."""
    pkg = _package(tmp_path, "fake", {"a": "X = 1\n", "sub/b": "from fake import X\n",
                                      "sub/c": "from fake.sub import Y\n", "d": "from fake import a\n"})
    (pkg / "__init__.py").write_text('"""API."""\nfrom fake.a import X\n', encoding="utf-8")
    (pkg / "sub" / "__init__.py").write_text("Y = 2\n", encoding="utf-8")
    proc = _run("--root", str(tmp_path))
    assert proc.returncode == 1
    assert "b.py:1: fake.sub.b imports from its own package's __init__ (fake)" in proc.stdout
    assert "c.py:1: fake.sub.c imports from its own package's __init__ (fake.sub)" in proc.stdout
    assert "fake.d" not in proc.stdout  # ``from fake import a`` imports the submodule a
    assert "2 problem(s)" in proc.stdout


def test_ident_layering(tmp_path: Path) -> None:
    """Inside aeropend_ident every import follows the arrows of docs/architecture.md
    (check_layout.LAYERS): sindy and greybox do not import each other, io imports no stage."""
    _package(tmp_path, "aeropend_ident", {
        "errors": "", "io/bags": "from aeropend_ident.errors import X\n",
        "sindy/core": "from aeropend_ident.io import bags\n",
        "greybox/fit": "from aeropend_ident.sindy.core import fit\n",
        "io/split": "from aeropend_ident.gap.run import run_gap\n", "gap/run": ""})
    proc = _run("--root", str(tmp_path))
    assert proc.returncode == 1
    assert ("fit.py:1: aeropend_ident.greybox.fit imports aeropend_ident.sindy.core: aeropend_ident.greybox "
            "may import only errors, io of aeropend_ident") in proc.stdout
    assert ("aeropend_ident.io.split imports aeropend_ident.gap.run: aeropend_ident.io may import only "
            "errors") in proc.stdout
    assert "2 problem(s)" in proc.stdout


def test_sim_layering_and_the_ros_shell(tmp_path: Path) -> None:
    """aeropend_sim's core never imports the simulator or its ROS shell; other packages import the
    simulator's own modules never, and rclpy / aeropend_sim.ros only from their nodes."""
    _package(tmp_path, "aeropend_sim", {
        "contract": "", "sim_core": "from aeropend_sim import contract\n",
        "params": "from aeropend_sim.sim_core import X\n", "ros/node_shell": "import rclpy\n"})
    _package(tmp_path, "aeropend_control", {
        "pid": "from aeropend_sim import contract\n", "controller_node": "import rclpy\n"
        "from aeropend_sim.ros.node_shell import run_node\n",
        "design": "import rclpy.node\nfrom aeropend_sim.ros import node_shell\n",
        "tuning": "from aeropend_sim.sim_core import X\n"})
    proc = _run("--root", str(tmp_path))
    out = proc.stdout
    assert proc.returncode == 1
    assert "aeropend_sim.params imports aeropend_sim.sim_core: aeropend_sim.params may import only " \
           "components, files of aeropend_sim" in out
    assert "design.py:1: aeropend_control.design imports rclpy outside the ROS shell" in out
    assert "design.py:2: aeropend_control.design imports aeropend_sim.ros.node_shell: aeropend_sim.ros is " \
           "for the ROS shell (nodes) only" in out
    assert "tuning.py:1: aeropend_control.tuning imports aeropend_sim.sim_core: a module of the simulator" \
        in out
    assert "controller_node" not in out and "aeropend_control.pid" not in out
    assert "4 problem(s)" in out


def test_an_arrow_back_up_between_packages_fails(tmp_path: Path) -> None:
    """aeropend_sim is the ground floor: a module of it importing aeropend_ident (the top floor) is
    refused, as is aeropend_bridge importing aeropend_control (same floor); ident importing control
    is an arrow down and passes."""
    _package(tmp_path, "aeropend_sim", {
        "contract": "", "params": "def f():\n    from aeropend_ident.greybox import rig_fit\n"})
    _package(tmp_path, "aeropend_control", {"design": "from aeropend_sim import contract\n"})
    _package(tmp_path, "aeropend_bridge", {"bridge": "from aeropend_control import design\n"})
    _package(tmp_path, "aeropend_ident", {
        "greybox/rig_fit": "from aeropend_control import design\nfrom aeropend_sim import contract\n"})
    proc = _run("--root", str(tmp_path))
    out = proc.stdout
    assert proc.returncode == 1
    assert "params.py:2: aeropend_sim.params imports aeropend_ident.greybox.rig_fit: aeropend_sim may " \
           "import only packages on a lower floor than its own (none;" in out
    assert "bridge.py:1: aeropend_bridge.bridge imports aeropend_control.design: aeropend_bridge may " \
           "import only packages on a lower floor than its own (aeropend_sim;" in out
    assert "2 problem(s)" in out
