"""Effect ``input_delay``: a transport delay (dead time) T_d between the command and the actuator.

The actuator sees τ(t − T_d). It has no term in the right-hand side: the simulator shifts the
zero-order-hold input in time (:mod:`aeropend_sim.simulate`), for any T_d, not only whole samples.
"""

from __future__ import annotations

from aeropend_sim.components.base import Diagnosis, Effect, FitBounds, Param

INPUT_DELAY = Param("actuator.input_delay", "s", "input (transport) delay T_d", sign="nonneg", absent=0.0,
                    fit=FitBounds(0.0, 1.0, False, 0.01), symbol="T_d")

EFFECT = Effect(
    name="input_delay",
    part="actuator",
    label="input delay",
    description="the actuator sees τ(t − T_d) (any T_d, not only whole samples)",
    order=20,
    params=(INPUT_DELAY,),
    diagnoses=(Diagnosis("input_delay", "actuator", "input/transport delay T_d: the actuator sees τ(t − T_d)",
                         ("input_delay",), ("theta",),
                         sindy_terms={"theta_dot": ("L/J·Δf(T_d)",), "i_a": ("Δv_a(T_d)/L_a",),
                                      "v_a": ("Δv_a(T_d)",)},
                         confusable_with=("actuator_lag", "motor_time_constant"),
                         truth={"input_delay": ((0.04, 0.1),)}),),
)
