"""The angle sensor's frame of a rig file (``recording_frame`` block; no rclpy).

A rig file may say how the recorded angle relates to the model's θ (the block ``gap`` writes into
``corrected_rig.yaml`` when it finds a sensor offset or gain, and that rigs measuring from another
zero carry)::

    recording_frame:
      theta_offset: {value: 0.05, unit: rad, source: "..."}
      theta_scale: {value: 1.02, unit: "1", source: "..."}

with θ_recorded = theta_scale·(θ_model − theta_offset). :func:`aeropend_sim.params.load_rig`
ignores the block; this module is its one reader: the identification replays the model in the
recording's frame (``aeropend_ident.greybox.parameters.rig_theta_offset``), the controller closes its loop
on θ_model = θ_recorded/s + offset, so the reference is the physical angle of the model,
whatever the sensor's zero and gain.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

import yaml

from aeropend_sim.files.safe_yaml import YamlRefusedError, load_yaml, parse_yaml


class FrameError(ValueError):
    """A malformed ``recording_frame`` block (the message names the key)."""


@dataclass(frozen=True)
class RecordingFrame:
    """θ_recorded = scale·(θ_model − offset).

    Attributes
    ----------
    offset : float
        θ_model at a recorded 0 [rad].
    scale : float
        Sensor gain [1], > 0.
    """

    offset: float = 0.0
    scale: float = 1.0

    def to_model(self, theta_recorded: float) -> float:
        """Model angle [rad] of a recorded angle [rad]."""
        return theta_recorded / self.scale + self.offset

    @property
    def identity(self) -> bool:
        """True when the recorded angle is the model's θ."""
        return self.offset == 0.0 and self.scale == 1.0


_KEYS = {"theta_offset": "rad", "theta_scale": "1"}


def read_recording_frame(rig_ref: str | Path) -> RecordingFrame:
    """The ``recording_frame`` of a rig file (path to a .yaml or a shipped rig's name).

    Returns the identity frame when the block is absent.

    Raises
    ------
    FrameError
        If the file cannot be read, or an entry is not ``{value, unit, source}`` with the unit
        rad (offset) / 1 (scale), a non-empty source, a finite value and, for the scale, a
        value > 0.
    """
    path = Path(rig_ref)
    try:
        if path.suffix in (".yaml", ".yml"):
            data = load_yaml(path, "a rig file")
        else:
            text = (resources.files("aeropend_sim") / "rigs" / f"{rig_ref}.yaml").read_text(encoding="utf-8")
            data = parse_yaml(text, f"{rig_ref}.yaml", "a rig file")
    except YamlRefusedError as exc:
        raise FrameError(str(exc)) from None
    except (OSError, yaml.YAMLError) as exc:
        raise FrameError(f"cannot read rig file {rig_ref!s}: {exc}") from exc
    block = data.get("recording_frame") if isinstance(data, dict) else None
    if not block:
        return RecordingFrame()
    if not isinstance(block, dict):
        raise FrameError(f"{rig_ref}: recording_frame must be a mapping, got {block!r}")
    values = {"theta_offset": 0.0, "theta_scale": 1.0}
    for key, unit in _KEYS.items():
        if key not in block:
            continue
        node = block[key]
        if not isinstance(node, dict) or "value" not in node:
            raise FrameError(f"{rig_ref}: recording_frame.{key} must be {{value, unit: {unit}, source}}, "
                             f"got {node!r}")
        if str(node.get("unit", "")).strip() != unit:
            raise FrameError(f"{rig_ref}: recording_frame.{key} has unit {node.get('unit')!r}; "
                             f"expected {unit!r}")
        if not str(node.get("source", "")).strip():
            raise FrameError(f"{rig_ref}: recording_frame.{key} has no 'source'")
        try:
            val = float(node["value"])
        except (TypeError, ValueError):
            raise FrameError(f"{rig_ref}: recording_frame.{key}.value = {node['value']!r} "
                             "is not a number") from None
        if not math.isfinite(val) or (key == "theta_scale" and val <= 0.0):
            raise FrameError(f"{rig_ref}: recording_frame.{key} = {val!r} must be finite"
                             + (" and > 0" if key == "theta_scale" else ""))
        values[key] = val
    return RecordingFrame(values["theta_offset"], values["theta_scale"])
