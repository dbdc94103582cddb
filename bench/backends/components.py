"""Study prototype (issue 37): the plant's physics written once, in an array-namespace style.

Not product code. It mirrors the structure issue 35 gives ``aeropend_sim`` (one contribution per
effect, summed by slot) closely enough to show that a compiled backend can compile physics written
that way: each contribution below is a plain function of floats (or arrays, or symbols) plus an
``xp`` namespace with the fixed operation set ``sin, cos, tanh, exp, sqrt, abs, sign, maximum,
minimum, where, power``. The equations are those of :mod:`aeropend_sim.model` (see its module
docstring and ``docs/model.md``); :func:`build` chooses the contributions from a rig's effect
switches at model-build time and generates the right-hand side that wires them together, with
every parameter an entry of a value vector ``p`` (changing a parameter never rebuilds or
recompiles anything).

State x = (θ, θ̇, i_a, ω₁, τ_f) as in :mod:`aeropend_sim.model`; input u = duty cycle after the
input delay.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from aeropend_sim.components.rotor.rotor_coulomb_friction import OMEGA_EPS
from aeropend_sim.params import Rig

#: tanh width of the rotor brush friction [rad/s]: the effect's declared value when the rig is silent
ROTOR_FRICTION_VELOCITY = OMEGA_EPS.absent


# ---------------------------------------------------------------- xp namespaces
class MathXP:
    """Scalar namespace (``math``-based), e.g. for LSODA."""

    sin, cos, tanh, exp, sqrt = math.sin, math.cos, math.tanh, math.exp, math.sqrt
    abs = staticmethod(abs)
    maximum, minimum = staticmethod(max), staticmethod(min)

    @staticmethod
    def sign(v):
        return math.copysign(1.0, v) if v != 0.0 else 0.0

    @staticmethod
    def where(c, a, b):
        return a if c else b

    @staticmethod
    def power(a, b):
        return a**b


class NumpyXP:
    """Array namespace (numpy)."""

    sin, cos, tanh, exp, sqrt, abs, sign = np.sin, np.cos, np.tanh, np.exp, np.sqrt, np.abs, np.sign
    maximum, minimum, where, power = np.maximum, np.minimum, np.where, np.power


# ---------------------------------------------------------------- contributions, by slot
# actuator: command -> armature voltage
def lag_rate(xp, u, tau_f, T_a):
    """First-order actuator lag, dτ_f/dt [1/s]."""
    return (u - tau_f) / T_a


def dead_zone(xp, tau, tau_dz):
    """Effective duty τ_e = max(0, τ − τ_dz)/(1 − τ_dz)."""
    return xp.maximum(tau - tau_dz, 0.0) / (1.0 - tau_dz)


def hbridge_voltage(xp, te, k0, k1, k2, k3):
    """Thesis Eq. 4.3 clipped at 0 V [V]."""
    return xp.maximum(k0 + k1 * xp.sqrt(xp.maximum(k2 * te + k3, 0.0)), 0.0)


def ideal_voltage(xp, te, v_supply):
    """Ideal PWM average v_a = v_supply·τ_e [V]."""
    return v_supply * te


# armature
def armature_rate(xp, v, i, w, R_a, L_a, K_omega):
    """di_a/dt [A/s] of thesis Eq. 3.5 (K_ω = 0 without back-EMF)."""
    return (v - R_a * i - K_omega * w) / L_a


# rotor torque terms [N·m]
def motor_torque(xp, i, K_t):
    return K_t * i


def rotor_viscous(xp, w, B_m):
    return -B_m * w


def rotor_coulomb(xp, w, T_c):
    return -T_c * xp.tanh(w / ROTOR_FRICTION_VELOCITY)


def propeller_drag(xp, w, K_d):
    return -K_d * w * xp.abs(w)


# thrust law [N]
def thrust_power_law(xp, w, gear_ratio, K_q, exponent):
    """f = K_q·|ω₂|^α·sign(ω₂), ω₂ = ω₁/n (thesis Eqs. 3.3-3.4)."""
    w2 = w / gear_ratio
    return K_q * xp.sign(w2) * xp.power(xp.abs(w2), exponent)


def thrust_square_law(xp, w, gear_ratio, K_q):
    w2 = w / gear_ratio
    return K_q * w2 * xp.abs(w2)


# rod torque terms over inertia [rad/s²]
def gravity(xp, th, mgd_over_J):
    return -mgd_over_J * xp.sin(th)


def rod_viscous(xp, thd, c_over_J):
    return -c_over_J * thd


def thrust_torque(xp, f, L_over_J):
    return L_over_J * f


def rod_dry_friction(xp, thd, coulomb_over_J, stribeck_over_J, stribeck_velocity, friction_velocity):
    """−(T_f/J + ((T_s − T_f)/J)·exp(−(θ̇/v_s)²))·tanh(θ̇/v_ε)."""
    level = coulomb_over_J + stribeck_over_J * xp.exp(-((thd / stribeck_velocity) ** 2))
    return -level * xp.tanh(thd / friction_velocity)


def end_stops(xp, th, thd, theta_min, theta_max, stop_stiffness, stop_damping):
    """One-sided spring-damper beyond θ_min/θ_max that pushes and never pulls."""
    upper = xp.minimum(-stop_stiffness * (th - theta_max) - stop_damping * thd, 0.0)
    lower = xp.maximum(-stop_stiffness * (th - theta_min) - stop_damping * thd, 0.0)
    return xp.where(th > theta_max, upper, 0.0) + xp.where(th < theta_min, lower, 0.0)


#: Penetration [rad] over which :func:`end_stops_ramped` phases its damping in (study variant).
CONTACT_RAMP = 0.01


def end_stops_ramped(xp, th, thd, theta_min, theta_max, stop_stiffness, stop_damping):
    """Study variant of :func:`end_stops` whose force is continuous in the state: the damping
    grows from 0 to ``stop_damping`` over the first :data:`CONTACT_RAMP` of penetration (the model's
    law jumps by −c_s·θ̇ at contact onset, which a fixed-step scheme integrates only to first order)."""
    d_up = xp.maximum(th - theta_max, 0.0)
    d_lo = xp.maximum(theta_min - th, 0.0)
    c_up = stop_damping * xp.minimum(d_up / CONTACT_RAMP, 1.0)
    c_lo = stop_damping * xp.minimum(d_lo / CONTACT_RAMP, 1.0)
    return (xp.minimum(-stop_stiffness * d_up - c_up * thd, 0.0)
            + xp.maximum(stop_stiffness * d_lo - c_lo * thd, 0.0))


# ---------------------------------------------------------------- build-time composition
@dataclass(frozen=True)
class Term:
    """One contribution wired into the rhs: its function, the local names it reads, the rig
    parameters (``section.name``) it takes, and the local name it defines (or the slot sum it
    adds to)."""

    fn: object
    args: tuple[str, ...]
    params: tuple[str, ...]
    out: str


def _terms(rig: Rig, ramped_stops: bool = False) -> list[Term]:
    """The contributions a rig's effect switches select, in evaluation order."""
    e = rig.effects
    if e.armature_inductance != "dynamic":
        raise NotImplementedError("prototype: dynamic armature only")
    t = []
    if e.actuator_lag and rig.actuator.lag_time_constant > 0.0:
        t.append(Term(lag_rate, ("u", "tau_f"), ("actuator.lag_time_constant",), "dtau_f"))
        t.append(Term(None, ("tau_f",), (), "tau"))
    else:
        t.append(Term(None, ("u",), (), "tau"))
    if e.dead_zone:
        t.append(Term(dead_zone, ("tau",), ("actuator.dead_zone",), "te"))
    else:
        t.append(Term(None, ("tau",), (), "te"))
    if e.hbridge_map:
        t.append(Term(hbridge_voltage, ("te",), tuple(f"actuator.hbridge_k{j}" for j in range(4)), "v"))
    else:
        t.append(Term(ideal_voltage, ("te",), ("actuator.v_supply",), "v"))
    kw = ("motor.K_omega",) if e.back_emf else ()
    t.append(Term(armature_rate if e.back_emf else _no_emf, ("v", "i", "w"),
                  ("motor.R_a", "motor.L_a", *kw), "di"))
    t.append(Term(motor_torque, ("i",), ("motor.K_t",), "+torque"))
    if e.viscous_friction:
        t.append(Term(rotor_viscous, ("w",), ("motor.B_m",), "+torque"))
    if e.coulomb_friction:
        t.append(Term(rotor_coulomb, ("w",), ("motor.T_c",), "+torque"))
    if e.propeller_drag:
        t.append(Term(propeller_drag, ("w",), ("motor.K_d",), "+torque"))
    if e.thrust_exponent:
        t.append(Term(thrust_power_law, ("w",), ("motor.gear_ratio", "thrust.K_q", "thrust.exponent"), "f"))
    else:
        t.append(Term(thrust_square_law, ("w",), ("motor.gear_ratio", "thrust.K_q"), "f"))
    t.append(Term(gravity, ("th",), ("pendulum.mgd_over_J",), "+acc"))
    if e.viscous_friction:
        t.append(Term(rod_viscous, ("thd",), ("pendulum.c_over_J",), "+acc"))
    t.append(Term(thrust_torque, ("f",), ("pendulum.L_over_J",), "+acc"))
    if e.coulomb_friction:
        dry = ("pendulum.coulomb_over_J", "pendulum.stribeck_over_J", "pendulum.stribeck_velocity",
               "pendulum.friction_velocity")
        t.append(Term(rod_dry_friction, ("thd",), dry, "+acc"))
    if e.end_stops:
        stops = ("pendulum.theta_min", "pendulum.theta_max", "pendulum.stop_stiffness",
                 "pendulum.stop_damping")
        t.append(Term(end_stops_ramped if ramped_stops else end_stops, ("th", "thd"), stops, "+acc"))
    return t


def _no_emf(xp, v, i, w, R_a, L_a):
    return (v - R_a * i) / L_a


@dataclass
class Built:
    """A composed model: the generated rhs source and function, its parameter names and values.

    ``rhs(xp, x, u, p)`` returns the 5 derivatives as a tuple; ``x`` is anything indexable by
    0..4 (tuple, numpy/JAX array, CasADi vector), ``p`` anything indexable by parameter position.
    ``functions`` maps the names used in the source to the contribution functions (a backend may
    replace them by compiled versions and ``exec`` the same source, as the numba backend does).
    """

    source: str
    functions: dict
    param_names: tuple[str, ...]
    p: np.ndarray
    rhs: object


def build(rig: Rig, ramped_stops: bool = False) -> Built:
    """Compose the rhs of ``rig`` from its contributions (see module docstring);
    ``ramped_stops`` takes the study's continuous contact law :func:`end_stops_ramped`."""
    terms = _terms(rig, ramped_stops)
    names: list[str] = []
    for term in terms:
        names += [n for n in term.params if n not in names]
    names.append("motor.J_m")
    lines = ["def rhs(xp, x, u, p):",
             "    th = x[0]", "    thd = x[1]", "    i = x[2]", "    w = x[3]", "    tau_f = x[4]",
             "    dtau_f = 0.0 * u", "    torque = 0.0", "    acc = 0.0"]
    functions = {}
    for term in terms:
        if term.fn is None:
            expr = term.args[0]
        else:
            functions[term.fn.__name__] = term.fn
            args = ", ".join(["xp", *term.args, *(f"p[{names.index(n)}]" for n in term.params)])
            expr = f"{term.fn.__name__}({args})"
        if term.out.startswith("+"):
            lines.append(f"    {term.out[1:]} = {term.out[1:]} + {expr}")
        else:
            lines.append(f"    {term.out} = {expr}")
    lines.append(f"    dw = torque / p[{names.index('motor.J_m')}]")
    lines.append("    return (thd, acc, di, dw, dtau_f)")
    source = "\n".join(lines) + "\n"
    namespace = dict(functions)
    exec(compile(source, "<aeropend rhs>", "exec"), namespace)
    values = np.array([_param(rig, n) for n in names])
    return Built(source, functions, tuple(names), values, namespace["rhs"])


def _param(rig: Rig, key: str) -> float:
    section, name = key.split(".")
    return float(getattr(getattr(rig, section), name))


def delay_split(rig: Rig, dt: float) -> tuple[int, float]:
    """Input delay as (whole samples, fraction of a sample in [0, 1)); (0, 0) without delay."""
    if not (rig.effects.input_delay and rig.actuator.input_delay > 0.0):
        return 0, 0.0
    n = rig.actuator.input_delay / dt
    whole = math.floor(n + 1e-9)
    frac = n - whole
    return whole, (0.0 if frac < 1e-9 else frac)


def delayed_pairs(duty: np.ndarray, whole: int, tau_before: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Actuator inputs over each sample interval: (u_a, u_b), each shape (N,).

    With a delay of ``whole + frac`` samples the actuator sees ``u_a[k] = duty[k − whole − 1]`` on
    the first ``frac·dt`` of interval k and ``u_b[k] = duty[k − whole]`` on the rest
    (``tau_before`` before the first command), the same shifted zero-order hold as
    :func:`aeropend_sim.simulation.simulate`.
    """
    padded = np.concatenate((np.full(whole + 1, tau_before), duty))
    n = duty.size
    return padded[:n], padded[1 : n + 1]


def pieces(frac: float, k: int, dt: float) -> tuple[int, float, int, float]:
    """Sub-steps of one sample: (n_a, h_a) on the first ``frac·dt`` (old delayed input), (n_b, h_b)
    on the rest, each sub-step at most dt/k long (k + 1 sub-steps at most)."""
    n_a = math.ceil(frac * k - 1e-9) if frac > 0.0 else 0
    n_b = math.ceil((1.0 - frac) * k - 1e-9)
    return n_a, (frac * dt / n_a if n_a else 0.0), n_b, (1.0 - frac) * dt / n_b
