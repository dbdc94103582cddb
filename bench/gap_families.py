"""The per-family cases of the independent gap benchmark: the ESC and voltage-amplifier rigs.

For each actuator family other than the thesis' H-bridge (``bench/bench_gap_independent.py``
holds that one): the hidden plant of :mod:`truth_plant` (:class:`truth_plant.EscPlant`,
:class:`truth_plant.AmplifierPlant`, written in a lab's own quantities), the lab's rig file of its
nominal plant (the conversion a lab does once: K_v and battery to ω_max, pulse widths to the
idle throttle, C_T and C_Q to K_q and K_d, masses and lengths to the rod's geometry), the truth
magnitudes the benchmark draws (:attr:`FamilyCases.ranges`, in the plant's units) and what the
diagnosis should report for each (:attr:`FamilyCases.expected`). Truth effect names are the
catalog's names; which of them a family's rig can have is the registry's business, never a list
here (``bench_gap_independent.catalog_cases``).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
from truth_plant import (
    G_STANDARD,
    RHO_AIR,
    AmplifierParams,
    AmplifierPlant,
    EscParams,
    EscPlant,
    RodParams,
    prop_thrust,
)

_SRC = "independent benchmark nominal plant (bench/truth_plant.py, converted as a lab does)"

#: Truth magnitudes shared by the rod and sensor effects of both families (factors unless said).
_ROD_RANGES: dict[str, list[tuple[float, float]]] = {
    "thrust_coefficient": [(0.75, 0.9), (1.1, 1.25)],
    "thrust_law": [(1.75, 1.9), (2.1, 2.25)],             # exponent on n around the half-throttle speed
    "gravity": [(0.75, 0.9), (1.12, 1.25)],
    "inertia": [(0.75, 0.88), (1.15, 1.35)],
    "viscous_friction": [(0.5, 0.75), (1.35, 2.0)],
    "end_stops": [(0.65, 0.85)],                          # fraction of the largest nominal angle
    "sensor_offset": [(-0.1, -0.02), (0.02, 0.1)],        # rad
    "sensor_scale": [(0.85, 0.94), (1.06, 1.15)],
    "angle_thrust_loss": [(0.2, 0.4)],
    "offset_drift": [(-3e-3, -1e-3), (1e-3, 3e-3)],       # rad/s
    "rod_air_drag": [(0.8, 2.5)],                         # 1/rad
}


def _q(value: float, unit: str, source: str = _SRC) -> dict[str, Any]:
    return {"value": float(value), "unit": unit, "source": source}


def _per_rev(value: float) -> float:
    """A propeller coefficient per (rev/s)² as one per (rad/s)²."""
    return value / (2.0 * math.pi) ** 2


def rod_section(rod: RodParams) -> dict[str, Any]:
    """The rig file's pendulum section: the geometry (the loader derives mgd/J and L/J) and c/J."""
    return {"mass": _q(rod.mass, "kg"), "com_distance": _q(rod.com, "m"), "thrust_arm": _q(rod.arm, "m"),
            "inertia": _q(rod.inertia, "kg*m^2"), "c_over_J": _q(rod.damping / rod.inertia, "1/s")}


def rod_expected(effect: str, magnitude: float, rod: RodParams) -> tuple[str, float, float] | None:
    """(rig field, true, nominal) of a rod or sensor effect, None for another effect."""
    mgd = rod.mass * G_STANDARD * rod.com / rod.inertia
    lj, cj = rod.arm / rod.inertia, rod.damping / rod.inertia
    table = {
        "gravity": ("pendulum.mgd_over_J", mgd * magnitude, mgd),
        "inertia": ("pendulum.L_over_J", lj / magnitude, lj),
        "viscous_friction": ("pendulum.c_over_J", cj * magnitude, cj),
        "coulomb_friction": ("pendulum.coulomb_over_J", magnitude, 0.0),
        "end_stops": ("pendulum.theta_max", magnitude, math.inf),
        "sensor_offset": ("measurement.theta_offset", -magnitude, 0.0),
        "sensor_scale": ("measurement.theta_scale", magnitude, 1.0),
        "thrust_law": ("thrust.exponent", magnitude, 2.0),
    }
    return table.get(effect)


def _arm_for(rod: RodParams, f_full: float, rng: np.random.Generator) -> RodParams:
    """The rod with the thrust arm that holds it at sin θ in [0.55, 0.8] at full command."""
    target = rng.uniform(0.55, 0.8)
    return dataclasses.replace(rod, arm=target * rod.mass * G_STANDARD * rod.com / f_full)


def _rod_variant(rod: RodParams, rng: np.random.Generator) -> RodParams:
    return rod.scaled(mass=rng.uniform(0.8, 1.25), com=rng.uniform(0.7, 1.3), inertia=rng.uniform(0.8, 1.25),
                      damping=rng.uniform(0.5, 1.5))


# ------------------------------------------------------------------------------ ESC
def esc_rig(p: EscParams, name: str) -> dict[str, Any]:
    """The lab's rig file of an ESC plant: the minimal ESC format (family, static map, response,
    dead time, K_q, geometry, c/J)."""
    span = p.pulse_max - p.pulse_min
    return {
        "name": name, "description": "nominal simulator of the independent benchmark (ESC rig)",
        "sample_period": _q(EscPlant.dt, "s"),
        "actuator": {"family": "esc",
                     "omega_max": _q(p.kv_rpm * 2.0 * math.pi / 60.0 * p.battery, "rad/s",
                                     "K_v × battery voltage (benchmark plant)"),
                     "idle_duty": _q((p.pulse_idle - p.pulse_min) / span, "1",
                                     "idle pulse in the calibrated range"),
                     "input_delay": _q(p.dead_time, "s")},
        "motor": {"T_m": _q(p.response, "s")},
        "thrust": {"K_q": _q(_per_rev(p.c_t * RHO_AIR * p.diameter**4), "N*s^2/rad^2", "C_T·ρ·D⁴/(2π)²")},
        "pendulum": rod_section(p.rod),
    }


def esc_variant(rng: np.random.Generator) -> EscParams:
    """An ESC rig other than the default: motor, battery, idle, response and rod drawn around it."""
    p = EscParams().scaled(kv_rpm=rng.uniform(0.8, 1.25), battery=rng.uniform(0.9, 1.1),
                           response=rng.uniform(0.6, 1.6), c_t=rng.uniform(0.85, 1.15))
    p = dataclasses.replace(p, pulse_idle=rng.uniform(1050.0, 1120.0), rod=_rod_variant(p.rod, rng))
    f_full = prop_thrust(p.c_t, p.diameter, EscPlant(p).omega_ss(1.0))
    return dataclasses.replace(p, rod=_arm_for(p.rod, f_full, rng))


def esc_expected(effect: str, magnitude: float, p: EscParams) -> tuple[str, float, float]:
    span = p.pulse_max - p.pulse_min
    w_max = p.kv_rpm * 2.0 * math.pi / 60.0 * p.battery
    k_q = _per_rev(p.c_t * RHO_AIR * p.diameter**4)
    table = {
        "esc_idle": ("actuator.idle_duty", (magnitude - p.pulse_min) / span,
                     (p.pulse_idle - p.pulse_min) / span),
        "esc_speed_range": ("actuator.omega_max", w_max * magnitude, w_max),
        "esc_response": ("motor.T_m", p.response * magnitude, p.response),
        "input_delay": ("actuator.input_delay", p.dead_time + magnitude, p.dead_time),
        "actuator_lag": ("actuator.lag_time_constant", magnitude, 0.0),
        "thrust_coefficient": ("thrust.K_q", k_q * magnitude, k_q),
    }
    return table.get(effect) or rod_expected(effect, magnitude, p.rod)  # type: ignore[return-value]


ESC_RANGES: dict[str, list[tuple[float, float]]] = {
    "esc_idle": [(1030.0, 1060.0), (1110.0, 1150.0)],     # µs (nominal 1080)
    "esc_speed_range": [(0.8, 0.9), (1.1, 1.2)],
    "esc_response": [(0.4, 0.7), (1.5, 3.0)],
    "input_delay": [(0.02, 0.06)],                        # s added to the nominal dead time
    "actuator_lag": [(0.03, 0.15)],                       # s
    "coulomb_friction": [(0.3, 1.5)],                     # rad/s² (mgd/J ≈ 40 s⁻²)
    **_ROD_RANGES,
}


# ------------------------------------------------------------------------------ amplifier
def amplifier_rig(p: AmplifierParams, name: str) -> dict[str, Any]:
    """The lab's rig file of an amplifier plant (Quanser-Aero style: data-sheet motor, no H-bridge)."""
    return {
        "name": name, "description": "nominal simulator of the independent benchmark (voltage amplifier)",
        "sample_period": _q(AmplifierPlant.dt, "s"),
        "actuator": {"family": "voltage_amplifier", "v_max": _q(p.gain * p.v_ref, "V",
                                                                "amplifier gain × full scale")},
        "motor": {"R_a": _q(p.R_a, "ohm"), "L_a": _q(p.L_a, "H"), "K_t": _q(p.k_t, "N*m/A"),
                  "K_omega": _q(p.k_e, "V*s/rad"), "J_m": _q(p.J_r, "kg*m^2"), "B_m": _q(p.B, "N*m*s/rad"),
                  "K_d": _q(_per_rev(p.c_q * RHO_AIR * p.diameter**5), "N*m*s^2/rad^2", "C_Q·ρ·D⁵/(2π)²")},
        "thrust": {"K_q": _q(_per_rev(p.c_t * RHO_AIR * p.diameter**4), "N*s^2/rad^2", "C_T·ρ·D⁴/(2π)²")},
        "pendulum": rod_section(p.rod),
    }


def amplifier_variant(rng: np.random.Generator) -> AmplifierParams:
    """An amplifier rig other than the default: motor, propeller and rod drawn around it."""
    k = rng.uniform(0.8, 1.25)
    p = AmplifierParams().scaled(R_a=rng.uniform(0.7, 1.4), k_t=k, k_e=k, J_r=rng.uniform(0.7, 1.4),
                                 B=rng.uniform(0.7, 1.4), c_t=rng.uniform(0.85, 1.15), c_q=rng.uniform(0.7,
                                                                                                       1.4))
    p = dataclasses.replace(p, rod=_rod_variant(p.rod, rng))
    plant = AmplifierPlant(p)
    f_full = prop_thrust(p.c_t, p.diameter, plant.steady_speed(plant.command(1.0)))
    return dataclasses.replace(p, rod=_arm_for(p.rod, f_full, rng))


def amplifier_expected(effect: str, magnitude: float, p: AmplifierParams) -> tuple[str, float, float]:
    k_q = _per_rev(p.c_t * RHO_AIR * p.diameter**4)
    k_d = _per_rev(p.c_q * RHO_AIR * p.diameter**5)
    table = {
        "amplifier_offset": ("actuator.v_offset", magnitude, 0.0),
        "input_delay": ("actuator.input_delay", magnitude, 0.0),
        "actuator_lag": ("actuator.lag_time_constant", magnitude, 0.0),
        "back_emf": ("motor.K_omega", p.k_e * magnitude, p.k_e),
        "armature_resistance": ("motor.R_a", p.R_a * magnitude, p.R_a),
        "torque_constant": ("motor.K_t", p.k_t * magnitude, p.k_t),
        "rotor_friction": ("motor.B_m", p.B * magnitude, p.B),
        "motor_time_constant": ("motor.J_m", p.J_r * magnitude, p.J_r),
        "propeller_drag": ("motor.K_d", k_d * magnitude, k_d),
        "rotor_brush_friction": ("motor.T_c", magnitude, 0.0),
        "thrust_coefficient": ("thrust.K_q", k_q * magnitude, k_q),
    }
    return table.get(effect) or rod_expected(effect, magnitude, p.rod)  # type: ignore[return-value]


AMPLIFIER_RANGES: dict[str, list[tuple[float, float]]] = {
    "amplifier_offset": [(-1.0, -0.3), (0.3, 1.0)],       # V (of 24 V full scale)
    "input_delay": [(0.012, 0.06)],                       # s (whole samples)
    "actuator_lag": [(0.03, 0.15)],                       # s
    "back_emf": [(0.8, 0.92), (1.08, 1.2)],
    "armature_resistance": [(0.7, 0.85), (1.2, 1.5)],
    "torque_constant": [(0.75, 0.9), (1.12, 1.3)],
    "rotor_friction": [(0.4, 0.7), (1.5, 2.5)],
    "motor_time_constant": [(0.4, 0.7), (1.5, 3.0)],
    "propeller_drag": [(0.6, 0.85), (1.2, 1.6)],
    "rotor_brush_friction": [(1e-3, 3e-3)],               # N·m
    "coulomb_friction": [(0.2, 1.0)],                     # rad/s² (mgd/J ≈ 24 s⁻²)
    **_ROD_RANGES,
}


@dataclass(frozen=True)
class FamilyCases:
    """What the independent benchmark needs of one actuator family (module doc)."""

    family: str
    dt: float
    channels: tuple[str, ...]
    ranges: dict[str, list[tuple[float, float]]]
    pairs: list[tuple[str, str]]
    nominal: Callable[[], Any]
    variant: Callable[[np.random.Generator], Any]
    plant: Callable[[Any, dict[str, float]], Any]
    rig: Callable[[Any, str], dict[str, Any]]
    expected: Callable[[str, float, Any], tuple[str, float, float]]
    base_delay: Callable[[Any], float]


ESC = FamilyCases(
    family="esc", dt=EscPlant.dt, channels=EscPlant.channels, ranges=ESC_RANGES,
    pairs=[("esc_idle", "viscous_friction"), ("input_delay", "gravity"), ("esc_response", "coulomb_friction"),
           ("esc_speed_range", "sensor_offset"), ("thrust_coefficient", "viscous_friction")],
    nominal=EscParams, variant=esc_variant, plant=EscPlant, rig=esc_rig, expected=esc_expected,
    base_delay=lambda p: p.dead_time,
)
AMPLIFIER = FamilyCases(
    family="voltage_amplifier", dt=AmplifierPlant.dt, channels=AmplifierPlant.channels,
    ranges=AMPLIFIER_RANGES,
    pairs=[("amplifier_offset", "viscous_friction"), ("input_delay", "gravity"),
           ("rotor_brush_friction", "coulomb_friction"), ("back_emf", "sensor_scale"),
           ("propeller_drag", "inertia")],
    nominal=AmplifierParams, variant=amplifier_variant, plant=AmplifierPlant, rig=amplifier_rig,
    expected=amplifier_expected, base_delay=lambda p: 0.0,
)
