"""The one YAML loader (issue 62, item 4): aliases and oversized files refused, at once, by name.

Each case puts a "billion laughs" alias bomb (nine lists of nine aliases to the list before:
about 400 bytes that expand to 9⁹ ≈ 3.9·10⁸ strings) where a lab's file has free text (a rig
file's ``description``, a preset's ``meta``) or in a ROS 2 parameters file, runs the command a
user runs, and checks: refused in under a second, exit status ≠ 0, one line naming the file, the
line of the first alias and what the file should be, no traceback.
"""

from __future__ import annotations

import time
from importlib import resources
from pathlib import Path

import pytest
import yaml

from aeropend_sim.files.safe_yaml import MAX_YAML_BYTES, YamlRefusedError, load_yaml, parse_yaml
from aeropend_sim.params import RigFileError, load_rig

SHIPPED_RIG = resources.files("aeropend_sim") / "rigs" / "thesis_rig.yaml"


def bomb(indent: str) -> str:
    """A billion-laughs block: keys ``l0`` .. ``l8`` at ``indent``; the first alias on its line 2."""
    lines = [f'{indent}l0: &l0 ["lol", "lol", "lol", "lol", "lol", "lol", "lol", "lol", "lol"]']
    for k in range(1, 9):
        lines.append(f"{indent}l{k}: &l{k} [{', '.join([f'*l{k - 1}'] * 9)}]")
    return "\n".join(lines) + "\n"


def rig_with_bomb(tmp_path: Path) -> Path:
    """The shipped thesis rig with the bomb as its ``description`` (a mapping instead of text)."""
    text = SHIPPED_RIG.read_text(encoding="utf-8")
    doc = yaml.safe_load(text)
    assert "description" in doc
    head = "".join(f"{line}\n" for line in text.splitlines() if not line.startswith("description:"))
    path = tmp_path / "bomb_rig.yaml"
    path.write_text("description:\n" + bomb("  ") + head, encoding="utf-8")
    return path


def one_line_refusal(err: str, path: Path, expected: str) -> str:
    lines = [x for x in err.splitlines() if x.strip()]
    assert len(lines) == 1, err
    assert "Traceback" not in err
    line = lines[0]
    assert str(path) in line and "alias *l0" in line and expected in line, line
    return line


def test_every_shipped_yaml_file_loads_without_aliases():
    """No shipped YAML needs an alias, so the loader refuses them altogether (module docstring)."""
    root = Path(__file__).resolve().parents[2] / "src"
    files = sorted(root.rglob("*.yaml"))
    assert len(files) >= 15
    for f in files:
        events = list(yaml.parse(f.read_text(encoding="utf-8")))
        assert not any(isinstance(e, yaml.AliasEvent) for e in events), f
        assert load_yaml(f, "a shipped file") == yaml.safe_load(f.read_text(encoding="utf-8"))
        assert f.stat().st_size < MAX_YAML_BYTES / 50


def test_shipped_rig_still_loads():
    rig = load_rig("thesis_rig")
    assert rig.family == "dc_hbridge"
    assert load_rig(Path(str(SHIPPED_RIG))).values() == rig.values()


def test_alias_bomb_in_a_rig_description_is_refused_by_rig_check(tmp_path, capsys):
    from aeropend_ident.cli.rig import main

    path = rig_with_bomb(tmp_path)
    t0 = time.perf_counter()
    status = main(["check", str(path)])
    elapsed = time.perf_counter() - t0
    assert status != 0
    assert elapsed < 1.0
    line = one_line_refusal(capsys.readouterr().err, path, "a rig file")
    assert f"{path}:3:12:" in line  # the first alias: line 3, column 12
    with pytest.raises(RigFileError, match="alias"):
        load_rig(path)


def test_alias_bomb_in_a_preset_meta_is_refused_by_csv_import(tmp_path, capsys):
    from aeropend_ident.cli.csv_import import main

    csv = tmp_path / "log.csv"
    csv.write_text("t,angle,pwm\n" + "".join(f"{k * 0.01:.2f},{0.1 * k:.1f},0.5\n" for k in range(50)))
    preset = tmp_path / "my_rig.yaml"
    preset.write_text("time_col: t\nangle_col: angle\nangle_unit: deg\ninput_col: pwm\nmeta:\n"
                      "  rig: a lab rig\n  notes:\n" + bomb("    "), encoding="utf-8")
    out = tmp_path / "bag"
    t0 = time.perf_counter()
    status = main([str(csv), "--preset", str(preset), "-o", str(out)])
    elapsed = time.perf_counter() - t0
    assert status != 0 and elapsed < 1.0
    line = one_line_refusal(capsys.readouterr().err, preset, "a CSV preset")
    assert f"{preset}:9:" in line
    assert not out.exists()


def test_alias_bomb_in_a_ros_parameters_file_is_refused_before_ros_starts(tmp_path, capsys):
    from aeropend_sim.ros.sim_node import main

    params = tmp_path / "sim.yaml"
    params.write_text("/**/aeropend_sim:\n  ros__parameters:\n    rig: thesis_rig\n    notes:\n"
                      + bomb("      "), encoding="utf-8")
    t0 = time.perf_counter()
    status = main(["sim_node", "--ros-args", "--params-file", str(params)])
    elapsed = time.perf_counter() - t0
    assert status == 2 and elapsed < 1.0
    line = one_line_refusal(capsys.readouterr().err, params, "a ROS 2 parameters file")
    assert f"{params}:6:" in line


def test_alias_in_a_parameter_value_is_refused():
    from aeropend_sim.excitation import ExcitationError
    from aeropend_sim.ros.excitation_node import ros_param_overrides

    assert ros_param_overrides(["--ros-args", "-p", "amplitude:=[0.1, 0.2]"]) == {"amplitude": [0.1, 0.2]}
    with pytest.raises(ExcitationError, match="parameter amplitude:1:13: refused: YAML alias"):
        ros_param_overrides(["--ros-args", "-p", "amplitude:=[&a [1, 2], *a]"])


def test_oversized_and_binary_files_are_refused_from_their_size_at_once(tmp_path):
    big = tmp_path / "big_rig.yaml"
    with open(big, "wb") as fh:  # sparse: 2 GB on paper, nothing on disk
        fh.truncate(2 << 30)
    t0 = time.perf_counter()
    refusal = r"big_rig.yaml: refused: 2048.0 MB, above the 1.0 MB limit for a rig file"
    with pytest.raises(RigFileError, match=refusal):
        load_rig(big)
    assert time.perf_counter() - t0 < 0.1
    nul = tmp_path / "nul.yaml"
    nul.write_bytes(b"name: x\n" + b"\0" * 1000)
    with pytest.raises(YamlRefusedError, match=r"nul.yaml: refused: a NUL byte on line 2"):
        load_yaml(nul, "a rig file")
    assert parse_yaml("a: 1\nb: [2, 3]\n", "t") == {"a": 1, "b": [2, 3]}
    with pytest.raises(YamlRefusedError, match="above the 100 bytes limit"):
        parse_yaml("x: " + "y" * 200, "t", max_bytes=100)
