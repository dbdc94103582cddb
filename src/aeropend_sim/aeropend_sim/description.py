"""Robot description (URDF) of an aeropendulum rig, for robot_state_publisher, RViz and Foxglove.

Pure Python (``xml.etree``), no rclpy, no xacro. :func:`urdf_for_rig` writes a URDF whose joint
names are the contract's (:data:`aeropend_sim.contract.JOINT_NAMES`):

* ``pendulum``: revolute joint of the rod about the pivot axis (−y), θ = 0 with the rod hanging
  straight down; limits from the rig's ``pendulum.theta_min`` / ``theta_max``. This is the
  only movable joint, so every transform robot_state_publisher derives from
  ``aeropend/joint_states`` is finite.
* ``motor`` and ``propeller``: **fixed** joints. The rig measures the rotor and propeller
  *speeds* only (``joint_states`` positions NaN for them, by the contract); an angle
  integrated from a speed would be invented, and a continuous joint with a NaN position gives
  a NaN transform that tf rejects. robot_state_publisher publishes fixed joints once on
  ``/tf_static`` and ignores their ``joint_states`` entries.

Dimensions. The thesis gives no lengths: its pendulum model needs only the ratios m·g·d/J and
L/J. The rod is drawn at the rig's *equivalent simple-pendulum length* ℓ = g / (m·g·d/J)
(the length of a point-mass pendulum with the same small-angle natural frequency; 0.634 m for
``thesis_rig``); motor, gear and propeller sizes are nominal (:class:`Geometry`), for display
only. No inertial elements: the description is for visualisation, not for a physics engine.

Command line: ``python -m aeropend_sim.description thesis_rig > aeropend.urdf``.
"""

from __future__ import annotations

import argparse
import math
import sys
import xml.etree.ElementTree as ET
from dataclasses import dataclass

from aeropend_sim.components.pendulum.rod import G
from aeropend_sim.contract import JOINT_NAMES
from aeropend_sim.params import load_rig


class DescriptionError(ValueError):
    """A rig cannot be drawn (a non-positive or non-finite pendulum parameter)."""


@dataclass(frozen=True)
class Geometry:
    """Visual dimensions of a rig [m] (see the module docstring for their sources).

    Attributes
    ----------
    rod_length : float
        Pivot to motor axis: the rig's equivalent simple-pendulum length.
    rod_radius, pivot_height : float
        Nominal: a 10 mm rod on a stand whose pivot is ``pivot_height`` above the base.
    motor_radius, motor_length : float
        Nominal can of a small geared DC motor (24 × 30 mm).
    gear_offset : float
        Nominal distance from the motor axis to the propeller shaft (the gear pair), along the rod.
    propeller_radius : float
        Nominal 5-inch propeller (0.127 m diameter).
    theta_min, theta_max : float
        Joint limits [rad] from the rig.
    """

    rod_length: float
    theta_min: float = -math.pi / 2
    theta_max: float = math.pi / 2
    rod_radius: float = 0.005
    pivot_height: float = 0.0
    motor_radius: float = 0.012
    motor_length: float = 0.030
    gear_offset: float = 0.020
    propeller_radius: float = 0.0635

    def __post_init__(self) -> None:
        for name in ("rod_length", "rod_radius", "motor_radius", "motor_length", "gear_offset",
                     "propeller_radius"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise DescriptionError(f"geometry {name} = {value!r} must be a finite positive length [m]")
        if not self.theta_min < self.theta_max:
            raise DescriptionError(f"theta_min {self.theta_min!r} must be below theta_max {self.theta_max!r}")

    @property
    def pivot_z(self) -> float:
        """Pivot height above the base [m]: the rod, motor and propeller clear the base plate."""
        return self.pivot_height or self.rod_length + self.gear_offset + self.propeller_radius + 0.05

    @classmethod
    def from_rig(cls, rig: object) -> Geometry:
        """Geometry of a loaded rig (:func:`aeropend_sim.params.load_rig`)."""
        p = rig.pendulum  # type: ignore[attr-defined]
        mgd_over_j = float(p.mgd_over_J)
        if not (math.isfinite(mgd_over_j) and mgd_over_j > 0):
            raise DescriptionError(f"pendulum.mgd_over_J = {mgd_over_j!r} 1/s²: cannot size the rod")
        return cls(rod_length=G / mgd_over_j, theta_min=float(p.theta_min), theta_max=float(p.theta_max))


def _f(x: float) -> str:
    return f"{x:.6g}"


def _xyz(*v: float) -> str:
    return " ".join(_f(x) for x in v)


def _visual(link: ET.Element, geometry: ET.Element, xyz: tuple[float, float, float],
            rpy: tuple[float, float, float], material: str) -> None:
    visual = ET.SubElement(link, "visual")
    ET.SubElement(visual, "origin", xyz=_xyz(*xyz), rpy=_xyz(*rpy))
    geo = ET.SubElement(visual, "geometry")
    geo.append(geometry)
    ET.SubElement(visual, "material", name=material)


def _cylinder(radius: float, length: float) -> ET.Element:
    return ET.Element("cylinder", radius=_f(radius), length=_f(length))


def _box(x: float, y: float, z: float) -> ET.Element:
    return ET.Element("box", size=_xyz(x, y, z))


def urdf(geometry: Geometry, name: str = "aeropend") -> str:
    """URDF text of an aeropendulum with ``geometry``.

    Frames: ``base_link`` on the floor (x forward, z up); the rod hangs along −z from the pivot
    at θ = 0 and swings in the x–z plane (a positive θ moves its end towards +x, the side the
    thrust pushes it to); the motor axis and the propeller shaft point along x.

    Returns
    -------
    str
        The URDF document (UTF-8 XML declaration included).
    """
    g = geometry
    pendulum, motor, propeller = JOINT_NAMES
    robot = ET.Element("robot", name=name)
    for mat, rgba in (("frame", "0.55 0.55 0.6 1"), ("rod", "0.85 0.85 0.9 1"),
                      ("motor", "0.8 0.45 0.1 1"), ("propeller", "0.1 0.1 0.12 1")):
        ET.SubElement(ET.SubElement(robot, "material", name=mat), "color", rgba=rgba)

    base = ET.SubElement(robot, "link", name="base_link")
    _visual(base, _box(0.30, 0.20, 0.02), (0, 0, 0.01), (0, 0, 0), "frame")
    _visual(base, _cylinder(0.01, g.pivot_z), (0, 0.04, g.pivot_z / 2), (0, 0, 0), "frame")

    rod = ET.SubElement(robot, "link", name="rod")
    _visual(rod, _cylinder(g.rod_radius, g.rod_length), (0, 0, -g.rod_length / 2), (0, 0, 0), "rod")
    joint = ET.SubElement(robot, "joint", name=pendulum, type="revolute")
    ET.SubElement(joint, "parent", link="base_link")
    ET.SubElement(joint, "child", link="rod")
    ET.SubElement(joint, "origin", xyz=_xyz(0, 0, g.pivot_z), rpy="0 0 0")
    ET.SubElement(joint, "axis", xyz="0 -1 0")
    ET.SubElement(joint, "limit", lower=_f(g.theta_min), upper=_f(g.theta_max), effort="0", velocity="100")

    motor_link = ET.SubElement(robot, "link", name="motor")
    _visual(motor_link, _cylinder(g.motor_radius, g.motor_length), (0, 0, 0), (0, math.pi / 2, 0), "motor")
    joint = ET.SubElement(robot, "joint", name=motor, type="fixed")
    ET.SubElement(joint, "parent", link="rod")
    ET.SubElement(joint, "child", link="motor")
    ET.SubElement(joint, "origin", xyz=_xyz(0, 0, -g.rod_length), rpy="0 0 0")

    prop = ET.SubElement(robot, "link", name="propeller")
    _visual(prop, _cylinder(0.004, 0.012), (0, 0, 0), (0, math.pi / 2, 0), "propeller")  # hub
    _visual(prop, _box(0.003, 0.012, 2 * g.propeller_radius), (0, 0, 0), (0, 0, 0), "propeller")  # blades
    joint = ET.SubElement(robot, "joint", name=propeller, type="fixed")
    ET.SubElement(joint, "parent", link="motor")
    ET.SubElement(joint, "child", link="propeller")
    # shaft beside the motor (gear pair), blades behind the motor can: thrust along +x
    ET.SubElement(joint, "origin", xyz=_xyz(-g.motor_length / 2 - 0.01, 0, g.gear_offset), rpy="0 0 0")

    ET.indent(robot)
    return '<?xml version="1.0"?>\n' + ET.tostring(robot, encoding="unicode") + "\n"


def urdf_for_rig(rig: str = "thesis_rig", name: str = "aeropend") -> str:
    """URDF of a shipped rig name or rig YAML path (see :func:`urdf`).

    Raises
    ------
    aeropend_sim.params.RigFileError
        The rig cannot be loaded.
    DescriptionError
        Its pendulum parameters cannot size the rod.
    """
    return urdf(Geometry.from_rig(load_rig(rig)), name=name)


def main(argv: list[str] | None = None) -> int:
    """``python -m aeropend_sim.description [RIG]``: print the URDF of a rig."""
    ap = argparse.ArgumentParser(description="print the URDF of an aeropendulum rig")
    ap.add_argument("rig", nargs="?", default="thesis_rig", help="shipped rig name or rig YAML path")
    a = ap.parse_args(argv)
    sys.stdout.write(urdf_for_rig(a.rig))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
