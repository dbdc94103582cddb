"""Component ``esc_rotor``: the speed response of a rotor behind an ESC, ω̇₁ = (ω_ss − ω₁)/T_m.

The ESC's static map (:mod:`..actuator.esc`) gives the set-point ω_ss(τ); the motor, propeller
and ESC together follow it with one time constant T_m (the response a step test shows).
"""

from __future__ import annotations

from aeropend_sim.components.base import POSITIVE, Component, Diagnosis, Param, Search, Term, scaled

T_M = Param("motor.T_m", "s", "rotor speed response time constant T_m (ESC + motor + propeller)",
            sign="positive", relative_truth=((0.3, 0.6), (1.7, 3.0)), symbol="T_m", typical=0.1,
            measure='steps or PRBS with holds near T_m (or a step with the rotor speed recorded)')


def response(xp, omega_sp, omega, T_m):
    """ω̇₁ = (ω_ss − ω₁)/T_m [rad/s²]."""
    return (omega_sp - omega) / T_m


def d_response_d_omega_sp(xp, omega_sp, omega, T_m):
    """∂ω̇₁/∂ω_ss [1/s]."""
    return 1.0 / T_m


def d_response_d_omega(xp, omega_sp, omega, T_m):
    """∂ω̇₁/∂ω₁ [1/s]."""
    return -1.0 / T_m


def steady_set_point(xp, y, T_m):
    """The set-point ω_ss that holds the rotor at a steady speed y [rad/s]."""
    return y + 0.0 * T_m


def response_range(ctx):
    """0.05 … 20 × nominal T_m."""
    return scaled(ctx.rig.motor.T_m, 0.05, 20.0, 2.0)


def apply_response(rig, v):
    """The rig with speed-response time constant T_m."""
    return rig.with_params("motor", T_m=v["T_m"])


COMPONENT = Component(
    name="esc_rotor",
    part="rotor",
    label="ESC speed response",
    description="first-order speed response to the ESC's set-point: ω̇₁ = (ω_ss − ω₁)/T_m",
    order=31,
    params=(T_M,),
    terms=(Term("rotor_response", 0, response, "ω̇₁ = (ω_ss − ω₁)/T_m",
                partials={"omega_sp": d_response_d_omega_sp, "omega": d_response_d_omega},
                inverse=steady_set_point),),
    diagnoses=(Diagnosis("esc_response", "motor",
                         "rotor speed response T_m of the ESC, motor and propeller wrong: "
                         "ω̇₁ = (ω_ss − ω₁)/T_m; the thrust follows the throttle more slowly or faster",
                         ("T_m",), ("theta",),
                         sindy_terms={"theta_dot": ("L/J·Δf(T_m)",), "omega_rotor": ("−ΔT_m·ω̇₁/T_m",)},
                         confusable_with=("actuator_lag",
                                          "input_delay"), screened=False, timing=True, order=107,
                         apply=apply_response,
                         search=(Search("T_m", "s", POSITIVE, "motor.T_m", "speed-response time constant T_m",
                                        response_range, "0.05 … 20 × nominal", log=True),)),),
)
