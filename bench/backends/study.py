"""Study prototype (issue 37): the test rig, the inputs and the LSODA reference shared by the
backend prototypes and ``bench/bench_sim_backends.py``."""

from __future__ import annotations

import contextlib

import numpy as np

from aeropend_sim.params import Rig, load_rig
from aeropend_sim.simulation import simulate

#: Simulated span of one replay [s] (issue 37's bar: 60 s at 490 Hz).
SPAN = 60.0
#: Parameters whose Jacobian d θ(t)/d p the study measures.
JAC_PARAMS = ("pendulum.mgd_over_J", "pendulum.c_over_J", "pendulum.L_over_J",
              "pendulum.coulomb_over_J", "motor.K_d")


def all_effects_rig(coulomb: bool = True, contact: bool = False) -> Rig:
    """thesis_rig with every dynamic effect on (sensor noise and quantisation stay off: they act on
    the measured channels, not on the ODE). Values of the effects the thesis rig does not measure
    follow ``bench/bench_control.py``'s perturbed plant and ``test/sim/test_model.py``: dead zone 3 %,
    lag 10 ms, input delay 5 ms (2.44 samples: a fractional delay), rotor brush friction
    2e-5 N·m, rod Coulomb 0.3 rad/s² with a Stribeck excess of 0.2 rad/s² over 0.1 rad/s (v_ε stays
    the stiff 0.01 rad/s), thrust exponent 1.9, end stops on at the thesis rig's ±π/2 (not reached by
    the inputs below, whose largest angle is ≈ 1 rad). ``coulomb=False`` switches the rod and rotor
    dry friction off; ``contact=True`` moves the upper stop to 0.65 rad, where the step and APRBS
    inputs spend 10-30 % of the time in contact."""
    rig = load_rig("thesis_rig").with_effects(
        hbridge_map=True, armature_inductance="dynamic", back_emf=True, dead_zone=True,
        viscous_friction=True, coulomb_friction=coulomb, propeller_drag=True, thrust_exponent=True,
        actuator_lag=True, input_delay=True, end_stops=True)
    rig = rig.with_params("actuator", dead_zone=0.03, lag_time_constant=0.01, input_delay=0.005)
    rig = rig.with_params("motor", T_c=2e-5)
    rig = rig.with_params("thrust", exponent=1.9)
    rig = rig.with_params("pendulum", coulomb_over_J=0.3, stribeck_over_J=0.2, stribeck_velocity=0.1)
    return rig.with_params("pendulum", theta_max=0.65) if contact else rig


def inputs(dt: float, seed: int = 0) -> dict[str, np.ndarray]:
    """The three input types over :data:`SPAN`: thesis Latin-hypercube steps, APRBS (50-500 ms
    holds) and a per-sample random duty (closed-loop-like: it changes every sample)."""
    from bench import bench_sim as b  # its input generators are the one home of the bench inputs

    rng = np.random.default_rng(seed)
    n = round(SPAN / dt)
    return {"step": b._lhs_steps(rng, n, dt), "aprbs": b._aprbs(rng, n, dt),
            "per_sample": rng.uniform(0.3, 1.0, n)}


def reference(rig: Rig, duty: np.ndarray) -> np.ndarray:
    """LSODA states (N, 5) of today's :func:`aeropend_sim.simulation.simulate`."""
    return simulate(rig, duty).x


@contextlib.contextmanager
def ramped_stops_in_model():
    """Within the block, :class:`aeropend_sim.model.PlantModel` uses the study's continuous contact
    law :func:`components.end_stops_ramped` (so LSODA gives its reference); restored after."""
    from aeropend_sim.model import PlantModel
    from bench.backends import components

    original = PlantModel._stop_accel

    def ramped(self, th, thd):
        return components.end_stops_ramped(components.MathXP, th, thd, self.th_min, self.th_max,
                                           self.k_s, self.c_s)

    PlantModel._stop_accel = ramped
    try:
        yield
    finally:
        PlantModel._stop_accel = original
