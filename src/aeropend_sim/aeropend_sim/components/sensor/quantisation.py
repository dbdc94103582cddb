"""Effect ``quantisation``: ADC/encoder quantisation of the measured channels, y = LSB·round(y/LSB).

Applied by :func:`aeropend_sim.simulation.measure`; an LSB of 0 leaves the channel as it is. θ̇ is
estimated, never quantised.
"""

from __future__ import annotations

from aeropend_sim.components.base import Diagnosis, Effect, Param, Search


def _lsb(name: str, unit: str, what: str) -> Param:
    return Param(f"sensors.{name}_quantum", unit, f"{what} LSB", sign="nonneg", absent=0.0)


def apply(rig, v):
    """The rig with an angle LSB q."""
    return rig.with_params("sensors", theta_quantum=v["theta_quantum"]).with_effects(quantisation=True)


EFFECT = Effect(
    name="quantisation",
    part="sensors",
    label="quantisation",
    description="y = LSB·round(y/LSB) per channel",
    order=72,
    params=(_lsb("theta", "rad", "angle"), _lsb("i_a", "A", "armature-current"),
            _lsb("v_a", "V", "armature-voltage"),
            _lsb("omega", "rad/s", "speed")),
    diagnoses=(Diagnosis("quantisation", "sensor",
                         "angle quantisation: θ_recorded = q·round(θ/q) (ADC/encoder LSB q)",
                         ("theta_quantum",), ("theta",), truth={"theta_quantum": ((0.008, 0.02),)},
                         kind="direct", order=220, apply=apply,
                         search=(Search("theta_quantum", "rad", (0.0, 1.0), "sensors.theta_quantum",
                                        "angle LSB q",
                                        lambda ctx: (0.0, 0.2, 0.0, 0.006),
                                        "detected from the lattice of recorded angles (not fitted)"),)),),
)
