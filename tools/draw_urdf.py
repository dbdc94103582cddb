"""Draw the aeropendulum's URDF (side view, x–z plane) from the *parsed* description.

The file is read with ``urdf_parser_py`` (PyPI ``urdfdom-py``); each link's visuals (cylinders,
boxes) are placed by forward kinematics through the parsed joints and drawn as their x–z
outlines, at θ = 0 and at a lifted angle. Used for ``docs/results/urdf_model.png``::

    python tools/draw_urdf.py [--urdf src/aeropend_sim/urdf/aeropend.urdf] [--theta 0.6]
"""

from __future__ import annotations

import argparse
import itertools
import math
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
from urdf_parser_py import urdf as urdf_parser

ROOT = Path(__file__).resolve().parents[1]


def _rot_axis(axis: np.ndarray, angle: float) -> np.ndarray:
    k = axis / np.linalg.norm(axis)
    kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + math.sin(angle) * kx + (1 - math.cos(angle)) * kx @ kx


def _rot_rpy(rpy: list[float]) -> np.ndarray:
    r, p, y = rpy
    return (_rot_axis(np.array([0, 0, 1.0]), y) @ _rot_axis(np.array([0, 1.0, 0]), p)
            @ _rot_axis(np.array([1.0, 0, 0]), r))


def link_poses(robot: urdf_parser.URDF,
               positions: dict[str, float]) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """World (position (3,), rotation (3, 3)) of every link frame for the given joint positions [rad]."""
    poses = {robot.get_root(): (np.zeros(3), np.eye(3))}
    pending = list(robot.joints)
    while pending:
        joint = next(j for j in pending if j.parent in poses)
        pending.remove(joint)
        p, r = poses[joint.parent]
        origin = joint.origin or urdf_parser.Pose([0, 0, 0], [0, 0, 0])
        p_c = p + r @ np.array(origin.xyz)
        r_c = r @ _rot_rpy(origin.rpy)
        if joint.type in ("revolute", "continuous"):
            r_c = r_c @ _rot_axis(np.array(joint.axis), positions.get(joint.name, 0.0))
        poses[joint.child] = (p_c, r_c)
    return poses


def _corners(geometry: object) -> np.ndarray:
    """Corner points (n, 3) of a visual's bounding solid in its own frame."""
    if isinstance(geometry, urdf_parser.Box):
        sx, sy, sz = (s / 2 for s in geometry.size)
    elif isinstance(geometry, urdf_parser.Cylinder):
        sx = sy = geometry.radius
        sz = geometry.length / 2
    else:
        raise ValueError(f"cannot draw {type(geometry).__name__} visuals")
    return np.array(list(itertools.product((-sx, sx), (-sy, sy), (-sz, sz))))


def _hull(points: np.ndarray) -> np.ndarray:
    """Convex hull (Andrew's monotone chain) of 2-D points (n, 2)."""
    pts = sorted(map(tuple, np.round(points, 9)))
    if len(pts) < 3:
        return np.array(pts)

    def half(seq: list[tuple[float, float]]) -> list[tuple[float, float]]:
        out: list[tuple[float, float]] = []
        for q in seq:
            while len(out) >= 2 and ((out[-1][0] - out[-2][0]) * (q[1] - out[-2][1])
                                     - (out[-1][1] - out[-2][1]) * (q[0] - out[-2][0])) <= 0:
                out.pop()
            out.append(q)
        return out

    return np.array(half(pts)[:-1] + half(pts[::-1])[:-1])


def draw(robot: urdf_parser.URDF, ax: plt.Axes, theta: float, alpha: float, root: bool = True) -> None:
    """Draw the visuals of ``robot`` at ``pendulum`` = ``theta`` on ``ax`` (x–z plane).

    ``root`` False leaves out the root link (the stand), drawn once already.
    """
    colors = {m.name: m.color.rgba for m in robot.materials if m.color is not None}
    poses = link_poses(robot, {"pendulum": theta})
    for link in robot.links:
        if link.name == robot.get_root() and not root:
            continue
        p, r = poses[link.name]
        for visual in link.visuals:
            origin = visual.origin or urdf_parser.Pose([0, 0, 0], [0, 0, 0])
            rv = r @ _rot_rpy(origin.rpy)
            world = (p + r @ np.array(origin.xyz)) + _corners(visual.geometry) @ rv.T
            outline = _hull(world[:, [0, 2]])
            name = visual.material.name if visual.material is not None else None
            ax.fill(outline[:, 0], outline[:, 1], color=colors.get(name, (0.5, 0.5, 0.5, 1))[:3],
                    alpha=alpha, edgecolor="k", linewidth=0.6)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--urdf", type=Path, default=ROOT / "src/aeropend_sim/urdf/aeropend.urdf")
    ap.add_argument("--theta", type=float, default=0.6, help="lifted pendulum angle to draw [rad]")
    ap.add_argument("--out", type=Path, default=ROOT / "docs/results/urdf_model.png")
    a = ap.parse_args(argv)
    robot = urdf_parser.URDF.from_xml_string(a.urdf.read_bytes())
    fig, ax = plt.subplots(figsize=(5.5, 6))
    draw(robot, ax, 0.0, 0.3)
    draw(robot, ax, 0.0, 0.5, root=False)
    draw(robot, ax, a.theta, 0.95, root=False)
    movable = ", ".join(f"{j.name} ({j.type})" for j in robot.joints if j.type != "fixed")
    ax.set_title(f"{robot.name}: parsed URDF, θ = 0 (faint) and {a.theta:g} rad\nmovable joints: {movable}",
                 fontsize=9)
    ax.set_xlabel("x [m] (thrust side +)")
    ax.set_ylabel("z [m]")
    ax.set_aspect("equal")
    ax.grid(alpha=0.3)
    fig.tight_layout()
    a.out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(a.out, dpi=110)
    print(f"wrote {a.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
