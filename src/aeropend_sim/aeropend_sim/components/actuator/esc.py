"""Family ``esc``: a brushless motor behind an electronic speed controller (ESC).

The ESC commutates the motor from its own controller: there is no armature voltage or current to
model or measure. The command τ (a fraction of the throttle range; a pulse width is mapped to it
by the CSV import presets) sets a steady rotor speed through the static throttle map

    ω_ss(τ) = ω_max·max(0, (τ_e − τ_0)/(1 − τ_0))^β

(τ_0: the idle/arming throttle below which the motor does not turn; ω_max: the speed at full
throttle; β: the curve exponent, 1 for a linear ESC). Why this form: an ESC in its usual
open-loop mode sets the motor's average voltage in proportion to the throttle above its start
point, and a brushless motor turns at about K_v times its voltage, so the speed is close to
linear in the throttle (β = 1); the resistive drop under the propeller load (∝ ω²) bends the curve
down at high throttle (β < 1), and ESCs with a throttle curve or thrust linearisation bend it the
other way (β > 1), so one exponent covers the measured curves with one more parameter. The rotor
follows ω_ss with a first-order response (:mod:`..rotor.esc_rotor`, time constant T_m), after the
shared input delay (the ``input_delay`` effect: ESC dead times of 0.2–1 s are common).
"""

from __future__ import annotations

from aeropend_sim.components.base import POSITIVE, Diagnosis, Family, Param, Search, Term, scaled

OMEGA_MAX = Param("actuator.omega_max", "rad/s", "steady rotor speed at full throttle ω_max", sign="positive",
                  relative_truth=((0.75, 0.88), (1.12, 1.25)), symbol="ω_max", typical=1000.0,
                  measure='K_v [rpm/V] × battery voltage × 2π/60, or the rotor speed recorded at full '
                          'throttle')
IDLE_DUTY = Param("actuator.idle_duty", "1", "idle/arming throttle τ_0: the rotor stands still below it",
                  sign="nonneg", below=1.0, absent=0.0, symbol="τ_0", typical=0.05,
                  measure='a balance table (command vs angle) down to the command where the rod lifts')
CURVE = Param("actuator.curve_exponent", "1", "throttle-curve exponent β (1: linear ESC)", sign="positive",
              absent=1.0, symbol="β", typical=1.0,
              measure='a balance or thrust table over the whole command range')


def speed(xp, tau, omega_max, idle_duty, curve_exponent):
    """Static throttle map ω_ss = ω_max·max(0, (τ_e − τ_0)/(1 − τ_0))^β [rad/s]."""
    return omega_max * xp.power(xp.maximum(0.0, (tau - idle_duty) / (1.0 - idle_duty)), curve_exponent)


def d_speed_d_tau(xp, tau, omega_max, idle_duty, curve_exponent):
    """∂ω_ss/∂τ_e [rad/s] (0 below τ_0; the one-sided slope at τ_0)."""
    s = (tau - idle_duty) / (1.0 - idle_duty)
    on = s > 0.0
    base = xp.where(on, s, 1.0)  # a safe base: 0**(β − 1) is infinite for β < 1
    slope = omega_max * curve_exponent * xp.power(base, curve_exponent - 1.0) / (1.0 - idle_duty)
    return xp.where(on, slope, 0.0)


def duty_of_speed(xp, y, omega_max, idle_duty, curve_exponent):
    """τ_e of a steady speed y [rad/s] (0 for y ≤ 0)."""
    frac = xp.power(xp.maximum(y, 0.0) / omega_max, 1.0 / curve_exponent)
    return xp.where(y > 0.0, idle_duty + (1.0 - idle_duty) * frac, 0.0)


#: Session-to-session drift of the full-throttle speed ω_max (σ of its log change, 8 %): an ESC
#: in its usual open-loop mode sets the motor voltage as a share of the battery's, so ω_max follows
#: the battery (a 3-cell LiPo from 12.6 V to about 10.5 V over its charge), as the supply voltage
#: of an H-bridge does.
SPEED_DRIFT_SIGMA = 0.08


def idle_range(ctx):
    """0 … min(0.6, 0.9·largest recorded duty); absent at the rig's τ_0."""
    off = ctx.rig.actuator.idle_duty
    return 0.0, min(0.6, 0.9 * ctx.duty_max), off, off + 0.05


def apply_idle(rig, v):
    """The rig with idle throttle τ_0."""
    return rig.with_params("actuator", idle_duty=v["idle_duty"])


def speed_range(ctx):
    """0.2 … 5 × nominal ω_max."""
    return scaled(ctx.rig.actuator.omega_max, 0.2, 5.0, 1.2)


def apply_speed(rig, v):
    """The rig with full-throttle speed ω_max."""
    return rig.with_params("actuator", omega_max=v["omega_max"])


FAMILY = Family(
    name="esc",
    part="actuator",
    label="brushless motor behind an ESC",
    description="throttle τ → rotor speed set-point ω_ss = ω_max·max(0, (τ − τ_0)/(1 − τ_0))^β, a "
                "first-order speed response T_m and a dead time; no armature channels",
    order=12,
    params=(OMEGA_MAX, IDLE_DUTY, CURVE),
    terms=(Term("drive", 10, speed, "ω_ss = ω_max·max(0, (τ_e − τ_0)/(1 − τ_0))^β",
                partials={"tau": d_speed_d_tau}, inverse=duty_of_speed),),
    families=("esc",),
    why_not="a parameter of the esc family: its rig file says actuator.family: esc",
    drive="omega_sp",
    lacks={
        "armature": "an ESC commutates a brushless motor from its own controller; there is no armature "
                    "voltage or current to model or measure (the speed map ω_ss(τ) contains the back-EMF)",
        "rotor_torque": "the ESC's static map ω_ss(τ) already holds the rotor's load torques (friction, "
                        "drag): only the speed response T_m remains",
    },
    channels=("theta", "theta_dot", "omega_rotor", "omega_prop"),
    refuses={"dead_zone": "on an ESC the idle throttle actuator.idle_duty τ_0 of the throttle map is the "
                          "dead zone; a second one could not be told apart from it"},
    usual_effects=("input_delay", "rod_viscous_friction"),
    diagnoses=(
        Diagnosis("esc_idle", "actuator",
                  "ESC idle/arming throttle τ_0 wrong: ω_ss = ω_max·max(0, (τ − τ_0)/(1 − τ_0))^β (the ESC's "
                  "dead zone; calibrating the throttle range moves it)",
                  ("idle_duty",), ("theta",),
                  sindy_terms={"theta_dot": ("L/J·Δf(τ_0)",), "omega_rotor": ("Δω_ss(τ_0)/T_m",)},
                  confusable_with=("input_delay",), truth={"idle_duty": ((0.02, 0.06), (0.15, 0.22))},
                  order=45, apply=apply_idle,
                  search=(Search("idle_duty", "1", (0.0, 0.95), "actuator.idle_duty", "idle throttle τ_0",
                                 idle_range, "0 … min(0.6, 0.9·largest recorded duty)"),)),
        Diagnosis("esc_speed_range", "actuator",
                  "full-throttle rotor speed ω_max of the ESC's map wrong (battery voltage, motor K_v): the "
                  "whole map ω_ss(τ) scales. With the angle alone it is a thrust-gain change (f ∝ ω₁²); the "
                  "recorded "
                  "rotor speed separates the two",
                  ("omega_max",), ("omega_rotor",),
                  sindy_terms={"theta_dot": ("L/J·Δf(ω_max)",), "omega_rotor": ("Δω_max·s(τ)^β/T_m",)},
                  confusable_with=("thrust_coefficient",), order=105, apply=apply_speed,
                  drift_sigma=SPEED_DRIFT_SIGMA,
                  search=(Search("omega_max", "rad/s", POSITIVE, "actuator.omega_max",
                                 "full-throttle speed ω_max",
                                 speed_range, "0.2 … 5 × nominal", log=True),)),
    ),
)
