"""The rig's robot description (URDF) parses, names the contract's joints and gives finite tf.

Parsed with ``urdf_parser_py`` (PyPI ``urdfdom-py``, the ROS URDF parser), not with the module
that writes it.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from urdf_parser_py import urdf as urdf_parser

from aeropend_sim.contract import JOINT_NAMES, Sample
from aeropend_sim.description import DescriptionError, G, Geometry, urdf, urdf_for_rig
from aeropend_sim.params import load_rig

SHIPPED = Path(__file__).resolve().parents[2] / "src" / "aeropend_sim" / "urdf" / "aeropend.urdf"


def _rotation(axis: np.ndarray, angle: float) -> np.ndarray:
    k = axis / np.linalg.norm(axis)
    kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + math.sin(angle) * kx + (1 - math.cos(angle)) * kx @ kx


def _link_origins(robot: urdf_parser.URDF, positions: dict[str, float]) -> dict[str, np.ndarray]:
    """World position of every link frame (the joints here have rpy = 0)."""
    out = {robot.get_root(): np.zeros(3)}
    rot = {robot.get_root(): np.eye(3)}
    for joint in robot.joints:  # written parent before child
        assert joint.origin.rpy == [0, 0, 0]
        p = out[joint.parent] + rot[joint.parent] @ np.array(joint.origin.xyz)
        r = rot[joint.parent]
        if joint.type != "fixed":
            r = r @ _rotation(np.array(joint.axis), positions[joint.name])
        out[joint.child], rot[joint.child] = p, r
    return out


def test_shipped_urdf_is_the_thesis_rigs_and_names_the_contract_joints() -> None:
    text = SHIPPED.read_text(encoding="utf-8")
    assert text == urdf_for_rig("thesis_rig")  # regenerate: python -m aeropend_sim.description
    robot = urdf_parser.URDF.from_xml_string(text.encode())
    assert robot.get_root() == "base_link"
    assert {j.name for j in robot.joints} == set(JOINT_NAMES)
    movable = [j for j in robot.joints if j.type != "fixed"]
    assert [(j.name, j.type) for j in movable] == [("pendulum", "revolute")]
    rig = load_rig("thesis_rig")
    pendulum = movable[0]
    assert (pendulum.limit.lower, pendulum.limit.upper) == pytest.approx(
        (rig.pendulum.theta_min, rig.pendulum.theta_max), abs=1e-5)
    rod = robot.link_map["rod"].visuals[0].geometry
    assert rod.length == pytest.approx(G / rig.pendulum.mgd_over_J, rel=1e-5)  # 0.634 m
    assert rod.length == pytest.approx(0.6338, abs=1e-4)


def test_joint_states_give_finite_transforms_and_theta_lifts_towards_the_thrust() -> None:
    robot = urdf_parser.URDF.from_xml_string(urdf_for_rig("thesis_rig").encode())
    sample = Sample(stamp_ns=0, theta=0.5, theta_dot=0.1, omega_rotor=300.0, omega_prop=49.0,
                    i_a=0.2, v_a=1.9, duty=0.4)
    js = sample.joint_state_fields()
    positions = dict(zip(js["name"], js["position"], strict=True))
    movable = [j.name for j in robot.joints if j.type != "fixed"]
    # robot_state_publisher uses the positions of movable joints only: all finite
    assert all(math.isfinite(positions[name]) for name in movable)
    assert math.isnan(positions["motor"]) and math.isnan(positions["propeller"])  # fixed in the URDF
    pivot = _link_origins(robot, {"pendulum": 0.0})["rod"]
    length = robot.link_map["rod"].visuals[0].geometry.length
    for theta in (0.0, 0.5, -0.3):
        motor = _link_origins(robot, {"pendulum": theta})["motor"]
        assert motor - pivot == pytest.approx([length * math.sin(theta), 0.0, -length * math.cos(theta)])
    # the propeller pushes the rod towards +x (positive θ): its blades sit at -x of the motor
    origins = _link_origins(robot, {"pendulum": 0.0})
    assert origins["propeller"][0] < origins["motor"][0]


def test_bad_rig_geometry_is_refused_with_the_value() -> None:
    with pytest.raises(DescriptionError, match=r"rod_length = -0.2 must be a finite positive length"):
        Geometry(rod_length=-0.2)
    with pytest.raises(DescriptionError, match=r"theta_min 1.0 must be below theta_max 0.5"):
        Geometry(rod_length=0.3, theta_min=1.0, theta_max=0.5)
    robot = urdf_parser.URDF.from_xml_string(urdf(Geometry(rod_length=0.25)).encode())
    assert robot.link_map["rod"].visuals[0].geometry.length == pytest.approx(0.25)
