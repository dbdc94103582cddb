"""The workspace builds with colcon and every package is a well-formed ament_python package."""

from __future__ import annotations

import configparser
import importlib
import os
import shutil
import subprocess
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

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


def test_colcon_build_installs_entry_points(tmp_path):
    colcon = shutil.which("colcon", path=str(Path(sys.executable).parent)) or shutil.which("colcon")
    if colcon is None:
        pytest.fail("colcon is not installed (requirements.txt pins colcon-common-extensions)")
    env = dict(os.environ, PATH=f"{Path(sys.executable).parent}:{os.environ.get('PATH', '')}")
    proc = subprocess.run(
        [colcon, "--log-base", str(tmp_path / "log"), "build", "--base-paths", str(ROOT / "src"),
         "--build-base", str(tmp_path / "build"), "--install-base", str(tmp_path / "install")],
        cwd=tmp_path, env=env, capture_output=True, text=True, timeout=300,
    )
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "4 packages finished" in proc.stdout
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
    # rig files ship with the package
    assert list((install / "aeropend_sim").rglob("thesis_rig.yaml"))
