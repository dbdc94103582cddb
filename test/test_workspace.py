"""The workspace builds with colcon and every package is a well-formed ament_python package."""

from __future__ import annotations

import configparser
import importlib
import os
import re
import shutil
import subprocess
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

# an expensive module fixture: under --dist loadgroup the module runs on one worker, which computes it once
pytestmark = pytest.mark.xdist_group("test_workspace")

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ["aeropend_sim", "aeropend_control", "aeropend_bridge", "aeropend_ident"]


@pytest.mark.parametrize("pkg", PACKAGES)
def test_package_is_ament_python_format_3(pkg):
    d = ROOT / "src" / pkg
    root = ET.parse(d / "package.xml").getroot()
    assert root.tag == "package" and root.get("format") == "3"
    assert root.findtext("name") == pkg
    assert root.find("export/build_type").text == "ament_python"
    assert (d / "resource" / pkg).is_file()
    cfg = configparser.ConfigParser()
    cfg.read(d / "setup.cfg")
    assert cfg["develop"]["script_dir"] == f"$base/lib/{pkg}"
    assert cfg["install"]["install_scripts"] == f"$base/lib/{pkg}"
    assert (d / pkg / "__init__.py").is_file()


def _console_scripts(pkg: str) -> list[tuple[str, str]]:
    from importlib.metadata import distribution

    dist = distribution(pkg.replace("_", "-"))
    return [(ep.name, ep.value) for ep in dist.entry_points if ep.group == "console_scripts"]


@pytest.mark.parametrize("pkg", PACKAGES)
def test_console_scripts_resolve(pkg):
    for name, target in _console_scripts(pkg):
        module, func = target.split(":")
        assert callable(getattr(importlib.import_module(module), func)), name


def _colcon() -> tuple[str, dict[str, str]]:
    colcon = shutil.which("colcon", path=str(Path(sys.executable).parent)) or shutil.which("colcon")
    if colcon is None:
        pytest.fail("colcon is not installed (requirements.txt pins colcon-common-extensions)")
    env = dict(os.environ, PATH=f"{Path(sys.executable).parent}:{os.environ.get('PATH', '')}")
    return colcon, env


@pytest.fixture(scope="module")
def colcon_ws(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """``colcon build`` of the four packages into a temporary workspace (built once)."""
    ws = tmp_path_factory.mktemp("colcon_ws")
    colcon, env = _colcon()
    proc = subprocess.run(
        [colcon, "--log-base", str(ws / "log"), "build", "--base-paths", str(ROOT / "src"),
         "--build-base", str(ws / "build"), "--install-base", str(ws / "install")],
        cwd=ws, env=env, capture_output=True, text=True, timeout=300,
    )
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "4 packages finished" in proc.stdout
    return ws


@pytest.mark.slow
def test_colcon_build_installs_entry_points(colcon_ws: Path) -> None:
    tmp_path = colcon_ws
    _, env = _colcon()
    install = tmp_path / "install"
    assert (install / "setup.bash").is_file()
    for pkg in PACKAGES:
        assert (install / pkg / "share" / pkg / "package.xml").is_file()
        assert (install / pkg / "share" / "ament_index" / "resource_index" / "packages" / pkg).is_file()
        for name, _ in _console_scripts(pkg):
            assert (install / pkg / "lib" / pkg / name).is_file(), f"{pkg}/{name} not installed"
    # sourcing setup.bash puts the package prefixes on AMENT_PREFIX_PATH as on a ROS install
    out = subprocess.run(["bash", "-c", f"source {install}/setup.bash && echo $AMENT_PREFIX_PATH"],
                         capture_output=True, text=True, env=env, timeout=60)
    assert str(install / "aeropend_sim") in out.stdout
    # rig files ship with the package (Python package data) and under share/ as ROS data
    assert list((install / "aeropend_sim").rglob("thesis_rig.yaml"))
    # the CSV import presets ship as package data of aeropend_ident.io
    presets = ROOT / "src" / "aeropend_ident" / "aeropend_ident" / "io" / "presets"
    assert {p.name for p in (install / "aeropend_ident").rglob("io/presets/*.yaml")} == {
        p.name for p in presets.glob("*.yaml")}
    rigs = install / "aeropend_sim" / "share" / "aeropend_sim" / "rigs"
    assert {p.name for p in rigs.glob("*.yaml")} == {
        p.name for p in (ROOT / "src" / "aeropend_sim" / "aeropend_sim" / "rigs").glob("*.yaml")}
    # the robot description and the RViz configuration
    share = install / "aeropend_sim" / "share" / "aeropend_sim"
    assert (share / "urdf" / "aeropend.urdf").read_text(encoding="utf-8") == (
        ROOT / "src" / "aeropend_sim" / "urdf" / "aeropend.urdf").read_text(encoding="utf-8")
    assert (share / "rviz" / "aeropend.rviz").is_file()
    assert (share / "launch" / "description.launch.py").is_file()
    # every package's ROS parameters files under share/<pkg>/config
    for pkg in PACKAGES:
        shipped = {p.name for p in (ROOT / "src" / pkg / "config").glob("*.yaml")}
        assert shipped, f"{pkg} has no config/*.yaml"
        assert {p.name for p in (install / pkg / "share" / pkg / "config").glob("*.yaml")} == shipped


#: Test folders of no single package (their files, not their subfolders): the workspace-level
#: tests at the top of test/ (the workspace, the layout, launch files of several packages, every
#: package's console scripts and result folders, the results docs, the README and the docs' links,
#: the public API), the firmware (C, not a ROS package) and graphs of several packages' nodes.
WORKSPACE_TEST_DIRS = ("test", "test/firmware", "test/ros")


def _package_test_dirs(pkg: str) -> list[Path]:
    """The test folders ``colcon test`` of ``pkg`` runs (its ``setup.cfg`` ``testpaths``)."""
    cfg = configparser.ConfigParser()
    cfg.read(ROOT / "src" / pkg / "setup.cfg")
    section = cfg["tool:pytest"]
    assert "python_files" not in section, f"{pkg}: select test folders (testpaths), not file patterns"
    dirs = [(ROOT / "src" / pkg / d).resolve() for d in section["testpaths"].split()]
    for d in dirs:
        assert d.is_dir() and d.is_relative_to(ROOT / "test"), f"{pkg}: testpaths {d} is no folder of test/"
    return dirs


def test_every_test_file_belongs_to_one_package_or_the_workspace() -> None:
    """``colcon test`` (per package) and ``./scripts/test.sh`` (all of test/) lose no test file."""
    owners: dict[Path, list[str]] = {}
    for pkg in PACKAGES:
        for folder in _package_test_dirs(pkg):
            matched = sorted(folder.rglob("test_*.py"))
            assert matched, f"{pkg}: test folder {folder} holds no test file"
            for path in matched:
                owners.setdefault(path, []).append(pkg)
    files = set((ROOT / "test").rglob("test_*.py"))
    workspace = {p for d in WORKSPACE_TEST_DIRS for p in (ROOT / d).glob("test_*.py")}
    doubles = {str(p.relative_to(ROOT)): pkgs for p, pkgs in owners.items() if len(pkgs) > 1}
    assert not doubles, f"test files run by more than one package: {doubles}"
    unowned = sorted(str(p.relative_to(ROOT)) for p in files - set(owners) - workspace)
    assert not unowned, ("test files no package runs (put them in a package's test folder, "
                         f"test/<package>/ or test/ros/<package>/, or a workspace folder): {unowned}")
    assert not workspace & set(owners)


#: The tests ``colcon test`` runs in :func:`test_colcon_test_runs_each_packages_tests`: whole modules of
#: both packages (the rig-file and YAML checks of aeropend_sim, the codec of aeropend_bridge), not all
#: 370 fast tests of the two again (94 s of the suite's time in the CI of fa1041f).
COLCON_SELECTION = "test_params or test_rig_format or test_safe_yaml or test_state_layout or test_protocol"

_RESULT = re.compile(r"(\d+) tests, (\d+) errors, (\d+) failures, (\d+) skipped")


@pytest.mark.slow
def test_colcon_test_runs_each_packages_tests(colcon_ws: Path) -> None:
    """``colcon test`` runs the packages' own tests (here a selection of the fast ones of two packages:
    colcon collects every test module of each package's ``testpaths``, so a module it cannot import
    is an error here, and runs the selected tests; the root suite runs them all anyway)."""
    colcon, env = _colcon()
    selected = ["aeropend_sim", "aeropend_bridge"]
    pick = ["-m", "not ros and not slow", "-k", COLCON_SELECTION]
    proc = subprocess.run(
        [colcon, "--log-base", str(colcon_ws / "log"), "test", "--base-paths", str(ROOT / "src"),
         "--build-base", str(colcon_ws / "build"), "--install-base", str(colcon_ws / "install"),
         "--packages-select", *selected, "--pytest-args", *pick],
        cwd=colcon_ws, env=env, capture_output=True, text=True, timeout=600,
    )
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "2 packages finished" in proc.stdout
    res = subprocess.run([colcon, "test-result", "--test-result-base", str(colcon_ws / "build"), "--all"],
                         cwd=colcon_ws, env=env, capture_output=True, text=True, timeout=60)
    print(res.stdout)
    assert res.returncode == 0, res.stdout + res.stderr
    per_package = {}
    for line in res.stdout.splitlines():
        m = _RESULT.search(line)
        if m and "pytest.xml" in line:
            per_package[Path(line.split(":")[0]).parent.name] = tuple(int(x) for x in m.groups())
    assert set(per_package) == set(selected), res.stdout
    for pkg, (tests, errors, failures, _) in per_package.items():
        # exactly the tests the root suite has in this package's files, with the same selection
        files = [str(d) for d in _package_test_dirs(pkg)]
        collected = subprocess.run([sys.executable, "-m", "pytest", "--collect-only", "-q", *pick, *files],
                                   cwd=ROOT, capture_output=True, text=True, timeout=120)
        m = re.search(r"(\d+)/\d+ tests collected|(\d+) tests collected", collected.stdout)
        assert m, collected.stdout[-2000:]
        expected = int(m.group(1) or m.group(2))
        print(f"{pkg}: colcon test ran {tests} tests, the root suite selects {expected}")
        assert tests == expected > 0
        assert (errors, failures) == (0, 0), f"{pkg}: {errors} errors, {failures} failures"
