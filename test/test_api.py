"""Each package's public API (``__all__`` of its ``__init__``): it resolves, it is cheap to import, it
loads no rclpy, and the reference page (docs/api.md, control's in docs/control.md) names it."""

from __future__ import annotations

import importlib
import json
import pkgutil
import re
import subprocess
import sys
from pathlib import Path

import pytest

from tools.check_layout import is_deprecated_reexport

ROOT = Path(__file__).resolve().parents[1]
#: Packages (and subpackages) that export an API, and the page that documents each.
APIS = {
    "aeropend_sim": "docs/api.md",
    "aeropend_ident": "docs/api.md",
    "aeropend_ident.io": "docs/api.md",
    "aeropend_ident.sindy": "docs/api.md",
    "aeropend_ident.greybox": "docs/api.md",
    "aeropend_ident.gap": "docs/api.md",
    "aeropend_bridge": "docs/api.md",
    "aeropend_control": "docs/control.md",
}
#: Packages whose names are imported on first use (PEP 562): importing them loads no submodule.
LAZY = ("aeropend_sim", "aeropend_ident", "aeropend_ident.io", "aeropend_ident.sindy",
        "aeropend_ident.greybox", "aeropend_ident.gap")
#: Heavy libraries a lazy package must not load at import.
HEAVY = ("numpy", "scipy", "numba", "pysindy", "matplotlib", "rosbags", "yaml")


def _probe(code: str) -> dict:
    """Run ``code`` in a fresh interpreter (nothing imported yet) and return the JSON it prints."""
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    return json.loads(proc.stdout.strip().splitlines()[-1])


@pytest.mark.parametrize("name", list(APIS))
def test_every_name_resolves_once_and_hides_no_submodule(name: str) -> None:
    """``__all__`` has no duplicate, every name resolves, and none is also a submodule of the
    package (importing that submodule would replace the exported function by the module), except a
    deprecated re-export kept for an old import path (``aeropend_sim.simulate``)."""
    pkg = importlib.import_module(name)
    names = pkg.__all__
    assert len(set(names)) == len(names)
    assert [n for n in names if not hasattr(pkg, n)] == []
    folder = Path(pkg.__path__[0])
    submodules = {m.name for m in pkgutil.iter_modules(pkg.__path__)
                  if m.ispkg or not is_deprecated_reexport(folder / f"{m.name}.py")}
    assert sorted(set(names) & submodules) == []
    assert set(names) <= set(dir(pkg))
    with pytest.raises(AttributeError, match=f"module '{name}' has no attribute 'no_such_name'"):
        _ = pkg.no_such_name


def test_the_lazy_lookup_returns_the_defining_modules_objects() -> None:
    import aeropend_ident.gap
    import aeropend_sim
    from aeropend_ident.gap import run as gap_run
    from aeropend_sim import simulation

    assert aeropend_sim.simulate is simulation.simulate
    assert aeropend_sim.PlantStepper is simulation.PlantStepper
    assert aeropend_ident.gap.run_gap is gap_run.run_gap
    assert aeropend_ident.run_gap is gap_run.run_gap


@pytest.mark.parametrize("name", list(APIS))
def test_importing_a_package_loads_no_rclpy_and_the_lazy_ones_nothing_heavy(name: str) -> None:
    """A fresh interpreter imports the package: no rclpy (the nodes stay apart); a lazy package
    loads none of its submodules and no heavy library, so a console script starts fast."""
    # aeropend_sim.lazy_api is the hook itself (a few lines, standard library only)
    out = _probe(f"import json, sys, {name}\n"
                 f"subs = [m for m in sys.modules\n"
                 f"        if m.startswith('{name}.') and m != 'aeropend_sim.lazy_api']\n"
                 f"heavy = [m for m in {HEAVY!r} if m in sys.modules]\n"
                 "print(json.dumps({'rclpy': 'rclpy' in sys.modules, 'subs': subs, 'heavy': heavy}))")
    assert out["rclpy"] is False
    if name in LAZY:
        assert out["subs"] == [] and out["heavy"] == [], out


def test_simulate_is_the_function_even_after_the_simulation_module_was_imported() -> None:
    """The reason ``simulate.py`` became ``simulation.py``: the package's ``simulate`` stays the
    function whatever was imported before (here every module the gap diagnosis uses)."""
    out = _probe("import json, aeropend_ident.gap.run, aeropend_sim.simulation\n"
                 "from aeropend_sim import simulate\n"
                 "print(json.dumps({'callable': callable(simulate), 'module': simulate.__module__}))")
    assert out == {"callable": True, "module": "aeropend_sim.simulation"}


def test_the_old_simulate_path_works_with_a_deprecation_warning() -> None:
    """``from aeropend_sim.simulate import ...`` (the path before the rename) keeps working."""
    out = _probe("import json, warnings\n"
                 "with warnings.catch_warnings(record=True) as seen:\n"
                 "    warnings.simplefilter('always')\n"
                 "    from aeropend_sim.simulate import PlantStepper, simulate\n"
                 "import aeropend_sim.simulation as new\n"
                 "same = simulate is new.simulate and PlantStepper is new.PlantStepper\n"
                 "told = [str(w.message) for w in seen if w.category is DeprecationWarning]\n"
                 "print(json.dumps({'same': same, 'warnings': told}))")
    assert out["same"] is True
    assert out["warnings"] == ["aeropend_sim.simulate is deprecated: import from aeropend_sim "
                               "(or aeropend_sim.simulation)"]


@pytest.mark.parametrize("name", list(APIS))
def test_the_reference_page_names_every_entry(name: str) -> None:
    page = (ROOT / APIS[name]).read_text(encoding="utf-8")
    if name == "aeropend_control":
        page = page[page.index("### Public API"):page.index("\n## ", page.index("### Public API"))]
    else:  # the package's own section: from its heading to the next one of its level or above
        heading = re.search(rf"^(#+) {re.escape(name)}\n", page, re.M)
        assert heading, f"{APIS[name]} has no section '{name}'"
        level = len(heading.group(1))
        rest = page[heading.end():]
        end = re.search(rf"^#{{1,{level}}} ", rest, re.M)
        page = rest[:end.start()] if end else rest
    pkg = importlib.import_module(name)
    assert [n for n in pkg.__all__ if f"`{n}`" not in page] == []


def test_no_module_uses_the_deprecated_simulate_path() -> None:
    """src, test, bench and tools import ``aeropend_sim.simulation`` (the old path is for labs' scripts)."""
    hits = [f"{p.relative_to(ROOT)}" for folder in ("src", "test", "bench", "tools")
            for p in (ROOT / folder).rglob("*.py")
            if re.search(r"aeropend_sim\.simulate import|import aeropend_sim\.simulate\b",
                         p.read_text(encoding="utf-8"))
            and p.name != "test_api.py" and not is_deprecated_reexport(p)]
    assert hits == []
