"""Batch closed loop of a :class:`~aeropend_control.controller_core.ControllerLoop` around the
simulated plant of its rig: the reference the ROS runs and the live-retune tests compare with."""

from __future__ import annotations

from collections.abc import Callable, Mapping

from aeropend_control.controller_core import ControllerLoop
from aeropend_sim.simulate import PlantStepper

PERIOD_NS = 2_048_000


Hook = Callable[[ControllerLoop], None]


def closed_loop(loop: ControllerLoop, n: int,
                before: Mapping[int, Hook] | None = None) -> list[tuple[float, float]]:
    """(measured θ, duty) of ``n`` lock-step samples of ``loop`` around a :class:`PlantStepper` of
    ``loop.settings.rig`` (θ, ω₁ and i_a given every sample: only cascades use the latter two);
    ``before[k](loop)`` runs before sample k (a retune, say)."""
    plant = PlantStepper(loop.settings.rig)
    s, out = plant.sample(), []
    for k in range(n):
        if before and k in before:
            before[k](loop)
        d = loop.on_sample(k * PERIOD_NS, s["theta"], s["omega_rotor"], s["i_a"])
        out.append((s["theta"], d))
        s = plant.step(d)
    return out
