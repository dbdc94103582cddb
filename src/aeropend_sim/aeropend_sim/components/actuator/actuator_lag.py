"""Effect ``actuator_lag``: a first-order lag T_a of the duty cycle, τ̇_f = (τ − τ_f)/T_a.

The lag state is x[4] = τ_f; the rest of the actuator chain reads τ_f instead of τ. Switched on
with T_a = 0 it does nothing (the state then follows τ).
"""

from __future__ import annotations

from aeropend_sim.components.base import Diagnosis, Effect, FitBounds, Param, Search, Term

LAG = Param("actuator.lag_time_constant", "s", "first-order actuator lag T_a", sign="nonneg", absent=0.0,
            fit=FitBounds(1e-4, 10.0, True), symbol="T_a", typical=0.05,
            measure='steps or PRBS with holds near the lag')


def rate(xp, u, tau_f, lag_time_constant):
    """τ̇_f = (u − τ_f)/T_a [1/s]."""
    return (u - tau_f) / lag_time_constant


def d_rate_d_u(xp, u, tau_f, lag_time_constant):
    """∂τ̇_f/∂u [1/s]."""
    return 1.0 / lag_time_constant


def d_rate_d_tau_f(xp, u, tau_f, lag_time_constant):
    """∂τ̇_f/∂τ_f [1/s]."""
    return -1.0 / lag_time_constant


def search_range(ctx):
    """1 ms … 1 s; absent at the rig's T_a (0 when off)."""
    off = ctx.rig.actuator.lag_time_constant if ctx.rig.effects.actuator_lag else 0.0
    return 1e-3, 1.0, off, max(off * 1.5, 0.05)


def apply(rig, v):
    """The rig with a first-order lag T_a."""
    return rig.with_params("actuator",
                           lag_time_constant=v["lag_time_constant"]).with_effects(actuator_lag=True)


EFFECT = Effect(
    name="actuator_lag",
    part="actuator",
    label="actuator lag",
    description="first-order lag of the duty cycle: τ̇_f = (τ − τ_f)/T_a",
    order=21,
    params=(LAG,),
    terms=(Term("lag", 10, rate, "τ̇_f = (τ − τ_f)/T_a",
                partials={"u": d_rate_d_u, "tau_f": d_rate_d_tau_f}),),
    active_when=lambda v: v["actuator.lag_time_constant"] > 0.0,
    diagnoses=(Diagnosis("actuator_lag", "actuator", "first-order actuator lag T_a: τ̇_f = (τ − τ_f)/T_a",
                         ("lag_time_constant",), ("theta",),
                         sindy_terms={"theta_dot": ("L/J·Δf(T_a)",), "i_a": ("Δv_a(T_a)/L_a",),
                                      "v_a": ("Δv_a(T_a)",)},
                         confusable_with=("input_delay", "motor_time_constant", "esc_response"),
                         truth={"lag_time_constant": ((0.05, 0.12),)}, order=30, apply=apply, timing=True,
                         search=(Search("lag_time_constant", "s", (0.0, 60.0), "actuator.lag_time_constant",
                                        "lag time constant T_a", search_range, "1 ms … 1 s", log=True),)),),
)
