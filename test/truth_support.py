"""The lab's side of the independent truth plant (``bench/truth_plant.py``) for tests and benches.

The truth plant's nominal parameters are the thesis' simulated plant with an ideal drive
(v_a = 2.32 V·τ); a lab describing it writes the shipped ``thesis_sim`` rig file with the H-bridge
map off and that supply voltage. One copy of that edit, used wherever a test or bench needs it.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import yaml

#: The shipped rig file the lab starts from.
THESIS_SIM = Path(__file__).resolve().parents[1] / "src/aeropend_sim/aeropend_sim/rigs/thesis_sim.yaml"
#: Armature voltage at τ = 1 of the truth plant's ideal drive [V].
IDEAL_SUPPLY_V = 2.32


def lab_rig_doc() -> dict[str, Any]:
    """A fresh ``thesis_sim`` rig document with the ideal 2.32 V drive (H-bridge map off)."""
    doc = yaml.safe_load(THESIS_SIM.read_text(encoding="utf-8"))
    doc["effects"]["hbridge_map"] = False
    doc["actuator"]["v_supply"]["value"] = IDEAL_SUPPLY_V
    return doc


def write_rig(doc: dict[str, Any], path: Path) -> Path:
    """Write a rig document as YAML to ``path``; returns ``path``."""
    path.write_text(yaml.safe_dump(doc, allow_unicode=True), encoding="utf-8")
    return path
