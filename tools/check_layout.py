#!/usr/bin/env python3
"""Check the source layout: no import cycle, no over-long function or module, no arrow back up.

Usage: ``python tools/check_layout.py [--root SRC] [--max-lines 80] [--max-module-lines 800]``

Rules (each violation is printed as ``file:line: message``; exit status 1 if any):

* **Import cycles.** Every ``.py`` file under ``--root`` (default: the repository's ``src/``) is
  a module; its name is its dotted path from the folder that holds the top-level package (the
  folder without an ``__init__.py`` above it, e.g. ``src/aeropend_sim``). Every ``import`` and
  ``from ... import`` anywhere in the file counts, including imports inside functions (lazy
  imports hide a cycle, they do not remove it) and ``if TYPE_CHECKING:`` blocks. ``from P import
  name`` is an edge to ``P.name`` when that is a module, otherwise to ``P``. Importing ``a.b.c``
  also imports the packages ``a`` and ``a.b``; those implicit package edges are *not* counted,
  so a package ``__init__`` may re-export names from its submodules as long as no submodule
  imports from its own package's ``__init__`` (submodules import their siblings directly). Any
  strongly connected component with more than one module is reported.
* **Function length.** A ``def`` (any nesting) longer than ``--max-lines`` lines of code, measured
  from the ``def`` line (decorators excluded) to its last line less its docstring: a function over
  it does more than one step and is split along its steps. A *table* (a function that only
  declares, such as an argument parser's options) may be longer: the comment line right above its
  ``def`` (or its first decorator) says so, ``# a table: WHAT IT DECLARES``.
* **Module length.** A module longer than ``--max-module-lines`` lines. A folder is one concept
  and holds as many modules as that concept needs; a module that grows past the limit holds more
  than one step of it and is split along its steps (``gap/which/``: data, fitting, screening, ...).
* **Own package ``__init__``.** A module imports a name from the ``__init__`` of a package it
  belongs to (``from aeropend_sim import load_rig`` inside ``aeropend_sim``): the ``__init__`` files
  re-export the public API, so such an import is a cycle waiting to happen and loads the whole
  API; submodules import their siblings directly.
* **Package floors**: a module imports only its own package and the packages on a lower floor
  of :data:`PACKAGE_FLOORS` (no arrow points back up between packages).
* **Layering** (docs/architecture.md): inside a package of :data:`LAYERS`, a module of one part
  (the first name below the package: ``aeropend_ident.gap``, ``aeropend_sim.params``) imports
  only the parts its row allows; across packages, :data:`SIMULATOR` modules are imported by their
  own package only; ``rclpy`` and ``aeropend_sim.ros`` are imported only by the ROS shell
  (:data:`ROS_SHELL`: the nodes) and ``aeropend_sim.ros`` also by :data:`PROCESS_RUNNERS` (modules
  that run nodes as processes). The rows apply to the packages present under ``--root``.

Plain Python (``ast``), no dependencies.
"""

from __future__ import annotations

import argparse
import ast
import re
import sys
from pathlib import Path

DEFAULT_ROOT = Path(__file__).resolve().parents[1] / "src"

#: Any part of the package (the ROS shell of aeropend_sim may import all of its library).
ANY = "*"
#: Layering inside a package: part -> the other parts of the same package it may import
#: (docs/architecture.md, "Layering"). Every part of a listed package needs a row.
LAYERS: dict[str, dict[str, set[str] | str]] = {
    "aeropend_ident": {
        "cli": {"gap", "sindy", "greybox", "io", "pipeline", "parallel", "progress", "errors"},
        "pipeline": {"greybox", "io", "errors"},
        # experiment design (issue 63): candidates from a gap diagnosis, sequences, its CLI
        "design": {"gap", "greybox", "io", "errors"},
        "gap": {"sindy", "greybox", "io", "parallel", "errors"},
        # Dask cases with progress bars (benches, gap --sessions, gap-batch)
        "parallel": {"greybox", "progress", "errors"},
        "progress": set(),
        "sindy": {"io", "errors"},
        "greybox": {"io", "errors"},
        "nodes": {"io", "errors"},
        "io": {"errors"},
        "errors": set(),
    },
    "aeropend_sim": {
        # the ROS shell: sim_node, excitation_node, node lifecycle, usage, QoS, domains, harness
        "ros": ANY,
        # the simulator: the plant node's functional core, the robot description
        "sim_core": {"simulation", "params", "components", "contract"},
        "description": {"params", "components", "contract"},
        # what a lab states about its rig: the `rig new` template, stated units (the command: ident cli)
        "rigfile": {"params", "components", "files"},
        # the shared core: plant library, rig files, topic contract, recordings, result folders
        "excitation": {"contract"},
        "simulation": {"compiled", "model", "params", "components"},
        "simulate": {"simulation"},  # deprecated re-export of simulation (its old name)
        "compiled": {"model", "params", "components"},
        "model": {"params", "components"},
        "params": {"components", "files"},
        "recording": {"contract"},
        "recording_frame": {"files"},
        "output_folder": set(),
        # the lazy public-API hook of every package __init__
        "lazy_api": set(),
        # the one YAML loader (aliases and oversized files refused)
        "files": set(),
        "contract": set(),
        "components": set(),
    },
}
#: The packages' floors: a module imports only its own package and packages on lower floors, so
#: every arrow between packages points down (aeropend_sim is the shared base of the other three).
PACKAGE_FLOORS = {"aeropend_sim": 0, "aeropend_control": 1, "aeropend_bridge": 1, "aeropend_ident": 2}
#: Modules of the simulator that only their own package imports (the other packages use the core).
SIMULATOR = ("aeropend_sim.sim_core", "aeropend_sim.description", "aeropend_sim.ros.sim_node",
             "aeropend_sim.ros.excitation_node")
#: The ROS shell: the only modules that import rclpy (functional core, ROS shell).
ROS_SHELL = re.compile(r"^aeropend_sim\.ros(\.|$)|^aeropend_\w+\.nodes(\.|$)|^aeropend_\w+\.\w+_node$")
#: Modules that run nodes as processes (no rclpy): they may import aeropend_sim.ros (domain, harness).
PROCESS_RUNNERS = ("aeropend_ident.pipeline",)


def _module_name(path: Path) -> str:
    """Dotted module name of ``path``: the parts below the first folder without ``__init__``."""
    parts = [path.stem] if path.name != "__init__.py" else []
    folder = path.parent
    while (folder / "__init__.py").is_file():
        parts.insert(0, folder.name)
        folder = folder.parent
    return ".".join(parts)


def _modules(root: Path) -> dict[str, Path]:
    skip = {".venv", "build", "install", "log", "__pycache__"}
    out: dict[str, Path] = {}
    for path in sorted(root.rglob("*.py")):
        if skip & set(path.relative_to(root).parts):
            continue
        if not (path.parent / "__init__.py").is_file():
            continue  # setup.py, launch files: not importable modules of a package
        out[_module_name(path)] = path
    return out


def _resolve_from(node: ast.ImportFrom, name: str, is_pkg: bool) -> str:
    if node.level == 0:
        return node.module or ""
    base = name.split(".") if is_pkg else name.split(".")[:-1]
    base = base[: len(base) - (node.level - 1)] if node.level > 1 else base
    return ".".join(base + ([node.module] if node.module else []))


def _imports(name: str, path: Path, modules: dict[str, Path]) -> dict[str, int]:
    """Modules of ``modules`` that ``name`` imports, each with the first line that does."""
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    is_pkg = path.name == "__init__.py"
    found: dict[str, int] = {}
    for node in ast.walk(tree):
        targets: list[str] = []
        if isinstance(node, ast.Import):
            targets = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = _resolve_from(node, name, is_pkg)
            for alias in node.names:
                sub = f"{base}.{alias.name}" if base else alias.name
                targets.append(sub if sub in modules else base)
        for target in targets:
            if target in modules and target != name:
                found.setdefault(target, node.lineno)
    return found


def _cycles(graph: dict[str, dict[str, int]]) -> list[list[str]]:
    """Strongly connected components with more than one node (Tarjan, iterative)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    out: list[list[str]] = []
    counter = 0
    for start in graph:
        if start in index:
            continue
        work = [(start, iter(graph[start]))]
        index[start] = low[start] = counter
        counter += 1
        stack.append(start)
        on_stack.add(start)
        while work:
            node, children = work[-1]
            advanced = False
            for child in children:
                if child not in index:
                    index[child] = low[child] = counter
                    counter += 1
                    stack.append(child)
                    on_stack.add(child)
                    work.append((child, iter(graph[child])))
                    advanced = True
                    break
                if child in on_stack:
                    low[node] = min(low[node], index[child])
            if advanced:
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[node])
            if low[node] == index[node]:
                comp = []
                while True:
                    top = stack.pop()
                    on_stack.discard(top)
                    comp.append(top)
                    if top == node:
                        break
                if len(comp) > 1:
                    out.append(sorted(comp))
    return out


def is_deprecated_reexport(path: Path) -> bool:
    """Whether ``path`` is a thin re-export module kept for an old import path (docstring "Deprecated",
    only imports, ``__all__`` and the ``warnings.warn`` call); the public-API test skips such modules."""
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    doc = ast.get_docstring(tree) or ""
    if not doc.startswith("Deprecated"):
        return False
    for node in tree.body[1:]:
        if isinstance(node, (ast.Import, ast.ImportFrom)):
            continue
        if isinstance(node, ast.Assign) and [getattr(t, "id", None) for t in node.targets] == ["__all__"]:
            continue
        call = node.value if isinstance(node, ast.Expr) else None
        if isinstance(call, ast.Call) and ast.unparse(call.func) == "warnings.warn":
            continue
        return False
    return True


def _external(path: Path) -> dict[str, int]:
    """Top-level names of every module ``path`` imports (absolute imports), each with its first line."""
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    found: dict[str, int] = {}
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                found.setdefault(alias.name.split(".")[0], node.lineno)
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            found.setdefault(node.module.split(".")[0], node.lineno)
    return found


def _own_init(name: str, targets: dict[str, int], modules: dict[str, Path]) -> list[str]:
    """Imports of ``name`` from the ``__init__`` of a package ``name`` belongs to."""
    parts = name.split(".")
    own = {".".join(parts[:i]) for i in range(1, len(parts))}
    return [f"{modules[name]}:{line}: {name} imports from its own package's __init__ ({target}): "
            "import the submodule that defines the name" for target, line in sorted(targets.items())
            if target in own and modules[target].name == "__init__.py"]


def _layering(name: str, targets: dict[str, int], modules: dict[str, Path]) -> list[str]:
    """Violations of :data:`LAYERS`, :data:`SIMULATOR`, :data:`ROS_SHELL` by module ``name``."""
    path = modules[name]
    parts = name.split(".")
    out = []
    rows = LAYERS.get(parts[0])
    for target, line in sorted(targets.items()):
        tparts = target.split(".")
        where = f"{path}:{line}: {name} imports {target}"
        if rows is not None and len(parts) > 1 and tparts[0] == parts[0] and len(tparts) > 1 \
                and tparts[1] != parts[1]:
            allowed = rows.get(parts[1])
            if allowed is None:
                out.append(f"{where}: {parts[0]}.{parts[1]} has no row in check_layout.LAYERS: "
                           "add it (and to docs/architecture.md)")
            elif allowed != ANY and tparts[1] not in allowed:
                out.append(f"{where}: {parts[0]}.{parts[1]} may import only "
                           f"{', '.join(sorted(allowed)) or 'nothing'} of {parts[0]} (docs/architecture.md)")
        floor, tfloor = PACKAGE_FLOORS.get(parts[0]), PACKAGE_FLOORS.get(tparts[0])
        if tparts[0] != parts[0] and floor is not None and tfloor is not None and tfloor >= floor:
            out.append(f"{where}: {parts[0]} may import only packages on a lower floor than its own "
                       f"({', '.join(p for p, f in PACKAGE_FLOORS.items() if f < floor) or 'none'}; "
                       "check_layout.PACKAGE_FLOORS)")
        if tparts[0] != parts[0] and any(target == m or target.startswith(m + ".") for m in SIMULATOR):
            out.append(f"{where}: a module of the simulator, for aeropend_sim only (use the core)")
        if target.startswith("aeropend_sim.ros") and not parts[0] == "aeropend_sim" \
                and not ROS_SHELL.search(name) and name not in PROCESS_RUNNERS:
            out.append(f"{where}: aeropend_sim.ros is for the ROS shell (nodes) only")
    line = _external(path).get("rclpy")
    if line is not None and not ROS_SHELL.search(name):
        out.append(f"{path}:{line}: {name} imports rclpy outside the ROS shell (functional core, ROS shell)")
    return out


#: The comment right above a ``def`` that marks the function as a table (exempt from the length rule).
TABLE_MARK = "# a table:"


def _code_lines(node: ast.FunctionDef | ast.AsyncFunctionDef) -> int:
    """Lines from the ``def`` to the function's end, less its docstring."""
    length = (node.end_lineno or node.lineno) - node.lineno + 1
    first = node.body[0] if node.body else None
    if (isinstance(first, ast.Expr) and isinstance(first.value, ast.Constant)
            and isinstance(first.value.value, str)):
        length -= (first.end_lineno or first.lineno) - first.lineno + 1
    return length


def _is_table(node: ast.FunctionDef | ast.AsyncFunctionDef, lines: list[str]) -> bool:
    """The line above the ``def`` (or above its first decorator) is a :data:`TABLE_MARK` comment."""
    top = min([node.lineno, *(d.lineno for d in node.decorator_list)])
    return top >= 2 and lines[top - 2].strip().startswith(TABLE_MARK)


def check(root: Path, max_lines: int = 80, max_module_lines: int = 800) -> list[str]:
    """All layout violations under ``root``, one ``file:line: message`` string each.

    Parameters
    ----------
    root : Path
        Folder holding the packages (the repository's ``src/``).
    max_lines : int
        Longest allowed function, in lines of code (docstring excluded; tables exempt).
    max_module_lines : int
        Longest allowed module, in lines.

    Returns
    -------
    list of str
        The violations; empty when the layout is fine.
    """
    modules = _modules(root)
    problems: list[str] = []
    graph = {name: _imports(name, path, modules) for name, path in modules.items()}
    for comp in _cycles(graph):
        members = set(comp)
        edges = [f"{a} -> {b} ({modules[a]}:{line})" for a in comp
                 for b, line in sorted(graph[a].items()) if b in members]
        problems.append(f"{modules[comp[0]]}:1: import cycle between {', '.join(comp)}: "
                        + "; ".join(edges))
    for name in modules:
        problems += _own_init(name, graph[name], modules)
        problems += _layering(name, graph[name], modules)
    for name, path in modules.items():
        text = path.read_text(encoding="utf-8")
        tree, lines = ast.parse(text, filename=str(path)), text.splitlines()
        for node in ast.walk(tree):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                length = _code_lines(node)
                if length > max_lines and not _is_table(node, lines):
                    problems.append(f"{path}:{node.lineno}: function {name}.{node.name} has "
                                    f"{length} lines of code (> {max_lines}): split it along its steps")
    for name, path in modules.items():
        length = len(path.read_text(encoding="utf-8").splitlines())
        if length > max_module_lines:
            problems.append(f"{path}:1: module {name} has {length} lines (> {max_module_lines}): split it "
                            "along its steps")
    return problems


def main(argv: list[str] | None = None) -> int:
    """Print the violations under ``--root``; exit status 1 if there are any."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--root", type=Path, default=DEFAULT_ROOT)
    parser.add_argument("--max-lines", type=int, default=80)
    parser.add_argument("--max-module-lines", type=int, default=800)
    args = parser.parse_args(argv)
    problems = check(args.root, args.max_lines, args.max_module_lines)
    for line in problems:
        print(line)
    modules = len(_modules(args.root))
    print(f"check_layout: {modules} modules under {args.root}, {len(problems)} problem(s)")
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main())
