"""Effect ``input_delay``: a transport delay (dead time) T_d between the command and the actuator.

The actuator sees τ(t − T_d). It has no term in the right-hand side: the simulator shifts the
zero-order-hold input in time (:mod:`aeropend_sim.simulation`), for any T_d, not only whole samples.
"""

from __future__ import annotations

from aeropend_sim.components.base import Diagnosis, Effect, FitBounds, Param, Search

INPUT_DELAY = Param("actuator.input_delay", "s", "input (transport) delay T_d", sign="nonneg", absent=0.0,
                    fit=FitBounds(0.0, 1.0, False, 0.01), symbol="T_d", typical=0.05,
                    measure="steps or PRBS recorded at 50 Hz or more (the response's first move after a "
                            "command change)")

def search_range(ctx):
    """Nominal … nominal + 0.3 s; absent at the rig's T_d (0 when off)."""
    off = ctx.rig.actuator.input_delay if ctx.rig.effects.input_delay else 0.0
    return 0.0, off + 0.3, off, off + 0.03


def apply(rig, v):
    """The rig with a transport delay T_d."""
    return rig.with_params("actuator", input_delay=v["input_delay"]).with_effects(input_delay=True)


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
                         confusable_with=("actuator_lag", "motor_time_constant", "esc_response"),
                         truth={"input_delay": ((0.04, 0.1),)}, order=40, apply=apply, timing=True,
                         search=(Search("input_delay", "s", (0.0, 5.0), "actuator.input_delay", "delay T_d",
                                        search_range, "nominal … nominal + 0.3 s"),)),),
)
