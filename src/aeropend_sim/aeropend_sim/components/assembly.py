"""Composition of a rig's active components and effects into the plant's equations.

The skeleton is the signal chain, fixed by the physics; the declarations fill its slots
(:data:`aeropend_sim.components.base.SLOTS`). With the state x = [θ, θ̇, i_a, ω₁, τ_f]:

1. lag: τ̇_f = (lag term) and τ = τ_f when the actuator lag is active, else τ̇_f = 0 and τ = u;
2. duty: τ_e = the ``duty`` terms applied in order (dead zone);
3. drive: q = the highest-order active ``drive`` term of τ_e (v_a, or an ESC's set-point ω_ss);
4. armature (families with one): dynamic L_a·di_a/dt = (q − R_a·i_a) + Σ armature terms(ω₁), or
   quasi-static i_a = (q + Σ armature terms(ω₁))/R_a (thesis Eqs. 3.5, 3.6);
5. rotor: J_m·ω̇₁ = Σ rotor-torque terms(i_a, ω₁) (DC motor) or ω̇₁ = rotor-response term(ω_ss, ω₁) (ESC);
6. gear, thrust: ω₂ = gear term(ω₁), f = thrust term(ω₂);
7. rod: θ̈ = Σ rod terms(θ, θ̇, f).

Sums run in the terms' ``order`` (the order of floating-point addition), so a rig simulated
bit for bit as it did before the registry existed (the one change since: ``xp.power(a, 2.0)`` is
the correctly rounded square, :mod:`aeropend_sim.components.xp`).

An :class:`Assembly` holds the active parts, the **effective** parameter values (an inactive
effect's parameters at their ``absent`` values) and the active terms per slot, and provides

* :attr:`Assembly.rhs`: the scalar right-hand side, generated once per rig (on first use) as
  Python source that calls the term functions with the parameters as constants (no branches on
  switches, no per-call lookups; :attr:`Assembly.rhs_source` shows it). :func:`chain_source` writes it; the
  compiled backend (:mod:`aeropend_sim.compiled`) has the same function write its family-wide
  source (parameters as entries of a vector, optional parts behind run-time flags);
* :meth:`Assembly.point` and :meth:`Assembly.slot_values`: every intermediate signal of the chain
  and each term's value, on floats (``xp.MATH``) or arrays (``xp.NUMPY``), for outputs,
  equation-error terms and the Jacobian;
* :meth:`Assembly.jacobian` (chain rule over the terms' partial derivatives) and
  :meth:`Assembly.steady_state` (inverse maps of the chain).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from functools import cached_property, lru_cache
from typing import Any

import numpy as np

from aeropend_sim.components import registry
from aeropend_sim.components.base import FD_STEP, Effect, Family, Part, Term
from aeropend_sim.components.states import CHAIN, I_A, N_CHAIN, OMEGA, TAU_F, THETA, THETA_DOT, StateLayout
from aeropend_sim.components.xp import MATH


@lru_cache(maxsize=256)
def _compiled(src: str, consts: tuple[tuple[str, Any], ...]) -> Any:
    """The ``rhs`` function of generated source ``src`` with its namespace (cached: rigs that differ
    only in the switches of inactive effects, and repeated constructions, share one function)."""
    namespace = {"_xp": MATH, "_ndarray": np.ndarray, **dict(consts)}
    exec(compile(src, "<generated rhs (aeropend_sim.components.assembly)>", "exec"), namespace)
    return namespace["rhs"]


class AssemblyError(ValueError):
    """A request the assembled model cannot satisfy (no armature on this family, ...)."""


#: A guard of generated source: a constant (the part acts or not) or a source expression.
Guard = bool | str


@dataclass(frozen=True)
class Wiring:
    """What :func:`chain_source` needs to write a model's equations as Python source.

    Attributes
    ----------
    armature : bool
        The family has an armature circuit (else its rotor follows a ``rotor_response`` term).
    drive : str
        Name of the family's drive quantity (``"v_a"`` or ``"omega_sp"``).
    slots : mapping
        Slot -> ``((term, guard), ...)`` in the terms' order. ``None`` as a guard: the term always
        acts; a source expression: it acts where the expression holds (a summed term then adds
        0.0, a duty term is skipped, a drive term gives way to the next lower one).
    lag, dynamic_current : bool or str
        Whether the actuator-lag state and the dynamic armature act: a constant, or a source
        expression tested at run time.
    arg : callable
        ``arg(name)`` -> source of the value of the parameter called ``name`` (a literal, a
        constant's name, ``p[3]``).
    states : tuple of str
        Variables of the effects' own states (after the chain's), each driven by its ``rate`` terms.
    fn : callable
        ``fn(term)`` -> name of the term's function in the generated namespace.
    xp : str
        Name of the ``xp`` namespace in the generated namespace.
    """

    armature: bool
    drive: str
    slots: Mapping[str, Sequence[tuple[Term, str | None]]]
    lag: Guard
    dynamic_current: Guard
    arg: Callable[[str], str]
    fn: Callable[[Term], str]
    xp: str = "_xp"
    states: tuple[str, ...] = ()

    def call(self, term: Term) -> str:
        """Source of one call of ``term`` (inputs by their names, parameters by :attr:`arg`)."""
        args = [a if a in term.inputs else self.arg(a) for a in term.arguments]
        return f"{self.fn(term)}({self.xp}, {', '.join(args)})"

    def total(self, slot: str, first: str | None = None, contact: bool | None = None,
              state: str | None = None) -> str:
        """Source of the sum of ``first`` and the slot's terms, in order (``contact``: only the
        terms whose :attr:`Term.contact` equals it; ``state``: only the rate terms of that state)."""
        expr = first
        for term, guard in self.slots.get(slot, ()):
            if contact is not None and term.contact != contact:
                continue
            if state is not None and term.state != state:
                continue
            call = self.call(term) if guard is None else f"({self.call(term)} if {guard} else 0.0)"
            expr = call if expr is None else f"({expr} + {call})"
        return expr if expr is not None else "0.0"


def _branch(guard: Guard, then: list[str], other: list[str]) -> list[str]:
    if guard is True:
        return then
    if guard is False:
        return other
    out = [f"if {guard}:", *("    " + line for line in then)]
    return out + (["else:", *("    " + line for line in other)] if other else [])


def _one_of(w: Wiring, slot: str, target: str) -> list[str]:
    """``target = <term>`` for a single-term slot: the last unguarded term, replaced where a guard
    of a later (higher-order) term holds."""
    terms = list(w.slots.get(slot, ()))
    if not terms:
        raise AssemblyError(f"no {slot} term")
    base = max((k for k, (_, g) in enumerate(terms) if g is None), default=None)
    if base is None:
        raise AssemblyError(f"the {slot} slot has no term that always acts")
    lines = [f"{target} = {w.call(terms[base][0])}"]
    for term, guard in terms[base + 1:]:  # ascending order: a later (higher-order) term wins
        lines = _branch(guard, [f"{target} = {w.call(term)}"], lines)
    return lines


def chain_source(w: Wiring) -> list[str]:
    """Body lines of the plant's equations, from the names ``theta, theta_dot, i_a, omega, tau_f``
    and :attr:`Wiring.states` (the state) and ``u`` (the duty cycle reaching the actuator).

    The lines define, in the order of the signal chain (module doc): ``dtau_f``, ``tau`` (after
    the duty terms: τ_e), the drive quantity (:attr:`Wiring.drive`), ``r_a`` (the armature
    resistance), ``i_a`` (redefined as the algebraic current when the armature is quasi-static),
    ``di_a``, ``domega``, ``omega_prop``, ``thrust``, ``dtheta_dot`` and ``d_<state>`` of each
    effect state. The sums keep the terms' order (the order of floating-point addition).
    """
    lines: list[str] = []
    lag = w.slots.get("lag", ())
    lag_on = [f"dtau_f = {w.call(lag[-1][0])}", "tau = tau_f"] if lag else []
    lines += _branch(w.lag if lag else False, lag_on, ["dtau_f = 0.0", "tau = u"])
    for term, guard in w.slots.get("duty", ()):
        lines += _branch(True if guard is None else guard, [f"tau = {w.call(term)}"], [])
    q = w.drive
    lines += _one_of(w, "drive", q)
    if w.armature:
        la, jm = w.arg("L_a"), w.arg("J_m")
        lines += _one_of(w, "resistance", "r_a")
        lines += _branch(w.dynamic_current, [f"di_a = {w.total('armature', f'({q} - r_a * i_a)')} / {la}"],
                         [f"i_a = {w.total('armature', q)} / r_a", "di_a = 0.0"])
        lines.append(f"domega = {w.total('rotor_torque')} / {jm}")
    else:
        lines.append("di_a = 0.0")
        lines += _one_of(w, "rotor_response", "domega")
    lines += _one_of(w, "gear", "omega_prop")
    lines += _one_of(w, "thrust", "thrust")
    lines.append(f"dtheta_dot = {w.total('rod')}")
    lines += [f"d_{v} = {w.total('rate', state=v)}" for v in w.states]
    return lines


#: Names :func:`chain_source` gives the derivatives of the chain's states, in their order.
CHAIN_RATES = ("theta_dot", "dtheta_dot", "di_a", "domega", "dtau_f")


def state_args(extra: Sequence[str] = ()) -> str:
    """Source of the state's names in order: the chain's, then the effects' states ``extra``."""
    return ", ".join((*(st.variable for st in CHAIN), *extra))


def rates(extra: Sequence[str] = ()) -> str:
    """Source of the state's derivatives in order (the names :func:`chain_source` defines)."""
    return ", ".join((*CHAIN_RATES, *(f"d_{v}" for v in extra)))


def effect_active(effect: Effect, switch: bool | str, values: Mapping[str, float]) -> bool:
    """Whether a switched effect acts: its switch is on and its ``active_when`` condition holds."""
    if not effect.is_on(switch):
        return False
    return effect.active_when is None or bool(effect.active_when(values))


class Assembly:
    """The active parts of one rig and the equations they compose (module doc).

    Parameters
    ----------
    family : str
        Actuator family name.
    values : mapping
        ``{"section.name": value}`` of every parameter the family has (the rig's values).
    switches : mapping
        ``{effect name: switch value}`` of every effect (inapplicable ones must be off).

    Attributes
    ----------
    family : Family
    active : tuple of Part
        The family's components and the active effects, by order.
    values : dict
        Effective parameter values by key (inactive effects' parameters at their absent value).
    slots : dict
        Slot -> active terms in order.
    lag, dynamic_current, armature : bool
        Actuator lag active; armature current a state; the family has an armature circuit.
    states : StateLayout
        The state vector: the chain's states, then the active effects' own states in their order.
    """

    def __init__(self, family: str, values: Mapping[str, float], switches: Mapping[str, bool | str]) -> None:
        built = registry.resolved(family)
        self.family: Family = built.family
        raw = dict(values)
        active: list[Part] = list(built.parts)
        effective = dict(raw)
        on_effects: list[Effect] = []
        for eff in built.effects:
            if effect_active(eff, switches.get(eff.name, eff.off), raw):
                on_effects.append(eff)
            else:
                for p in eff.params:
                    effective[p.key] = p.absent if p.absent is not None else raw[p.key]
        self.active: tuple[Part, ...] = tuple(sorted((*active, *on_effects), key=lambda p: (p.order, p.name)))
        self.values = effective
        self.by_name = {k.partition(".")[2]: v for k, v in effective.items()}
        slots: dict[str, list[Term]] = {}
        for part in self.active:
            for term in part.terms:
                slots.setdefault(term.slot, []).append(term)
        self.slots: dict[str, tuple[Term, ...]] = {
            k: tuple(sorted(v, key=lambda t: t.order)) for k, v in slots.items()}
        # each active term's arguments: an input name, or its parameter's effective value (bound once)
        self._args: dict[int, tuple[tuple[bool, Any], ...]] = {
            id(t): tuple((a in t.inputs, a if a in t.inputs else self.by_name[a]) for a in t.arguments)
            for terms in self.slots.values() for t in terms}
        self._params: dict[int, tuple[float, ...]] = {}  # :meth:`_params_of`
        self.lag = bool(self.slots.get("lag"))
        self.armature = "armature" not in self.family.lacks
        names = {p.name for p in self.active}
        self.dynamic_current = self.armature and "armature_inductance" in names
        self.drive_name = self.family.drive
        self.states = StateLayout.of(st for part in self.active for st in part.states)

    @cached_property
    def _generated(self) -> tuple[str, Any]:
        # written and compiled on first use: many assemblies (a fit's candidate rigs, the motor
        # steady state of a replay's start) never call the scalar right-hand side
        return self._generate_rhs()

    @cached_property
    def rhs(self) -> Callable[[float, Any, float], list[float]]:
        """The scalar right-hand side ``rhs(t, x, u)`` -> dx/dt (list of :attr:`states` ``.size``
        floats), generated on first use (module doc)."""
        return self._generated[1]

    # ------------------------------------------------------------------ helpers
    def has(self, name: str) -> bool:
        """Whether the part (component or effect) called ``name`` is active."""
        return any(p.name == name for p in self.active)

    def _one(self, slot: str) -> Term:
        terms = self.slots.get(slot, ())
        if not terms:
            raise AssemblyError(f"the {self.family.name} family has no {slot} term")
        return terms[-1]  # the highest active order (the drive map an effect replaces)

    def _with(self, values: Mapping[str, Any]) -> dict[str, Any]:
        out = dict(self.by_name)
        out.update(values)
        return out

    def _eval(self, term: Term, xp: Any, inputs: Mapping[str, Any]) -> Any:
        """The term at ``inputs`` with its parameters' effective values."""
        return term.fn(xp, *[inputs[v] if is_input else v for is_input, v in self._args[id(term)]])

    def _partial(self, term: Term, name: str, inputs: Mapping[str, Any]) -> Any:
        """∂term/∂``name`` on floats at ``inputs`` with its parameters' effective values:
        :meth:`~aeropend_sim.components.base.Term.partial` at the mapping :meth:`_with` makes (the same
        arguments), without copying every parameter into it."""
        if name not in term.inputs:
            return 0.0
        d = term.partials.get(name)
        if d is not None:
            return d(MATH, *[inputs[v] if is_input else v for is_input, v in self._args[id(term)]])
        return term.partial(MATH, name, self._with(inputs))

    def _bound(self, term: Term, name: str) -> Callable[[float], Any]:
        """``term`` on floats as a function of its input ``name`` alone: the call :meth:`_eval` makes
        (the same function, the same arguments in the same order), without building the argument
        list and the inputs' mapping at every call (a controller's hot path calls it per sample).

        Raises
        ------
        AssemblyError
            If the term reads another input too.
        """
        args = self._args[id(term)]
        if [v for is_input, v in args if is_input] != [name]:
            raise AssemblyError(f"term {term.label!r} reads {[v for i, v in args if i]}, not {name!r} alone")
        k = next(i for i, (is_input, _) in enumerate(args) if is_input)
        fn, before, after = term.fn, tuple(v for _, v in args[:k]), tuple(v for _, v in args[k + 1:])
        return lambda value: fn(MATH, *before, value, *after)

    @cached_property
    def _propeller_scalar(self) -> tuple[Callable[[float], Any], Callable[[float], Any]]:
        return self._bound(self._one("gear"), "omega"), self._bound(self._one("thrust"), "omega_prop")

    def thrust_scalar(self, omega: float) -> Any:
        """Thrust f [N] at the rotor speed ω₁ [rad/s], a float: :meth:`propeller`'s second value on
        ``MATH``, bit for bit, at a fraction of its cost per call."""
        gear, thrust = self._propeller_scalar
        return thrust(gear(omega))

    # ------------------------------------------------------------------ generated right-hand side
    @property
    def rhs_source(self) -> str:
        """Python source of :attr:`rhs` (for reading and for a compiled backend)."""
        return self._generated[0]

    def _generate_rhs(self) -> tuple[str, Any]:
        consts: dict[str, Any] = {}  # term functions and non-finite parameters by their names in the source
        names: dict[int, str] = {}

        def fn(term: Term) -> str:
            if id(term) not in names:
                names[id(term)] = f"_f{len(names) + 1}"
                consts[names[id(term)]] = term.fn
            return names[id(term)]

        def arg(name: str) -> str:
            v = float(self.by_name[name])
            if math.isfinite(v):
                return repr(v)
            consts[f"_c_{name}"] = v
            return f"_c_{name}"

        extra = self.states.extra_names
        wiring = Wiring(armature=self.armature, drive=self.drive_name,
                        slots={k: tuple((t, None) for t in v) for k, v in self.slots.items()},
                        lag=self.lag, dynamic_current=self.dynamic_current, arg=arg, fn=fn, states=extra)
        lines = ["def rhs(t, x, u):",
                 "    if type(x) is _ndarray:",
                 "        x = x.tolist()",
                 f"    {state_args(extra)} = x",
                 *("    " + line for line in chain_source(wiring)),
                 f"    return [{rates(extra)}]"]
        src = "\n".join(lines) + "\n"
        return src, _compiled(src, tuple(sorted(consts.items(), key=lambda kv: kv[0])))

    # ------------------------------------------------------------------ evaluation on floats or arrays
    def duty_chain(self, xp: Any, tau: Any) -> Any:
        """τ_e of the duty cycle τ after the lag (the ``duty`` terms in order)."""
        for term in self.slots.get("duty", ()):
            tau = self._eval(term, xp, {"tau": tau})
        return tau

    def drive(self, xp: Any, tau: Any) -> Any:
        """Drive quantity (v_a [V] or ω_ss [rad/s]) of the duty cycle τ after the lag."""
        return self._eval(self._one("drive"), xp, {"tau": self.duty_chain(xp, tau)})

    def propeller(self, xp: Any, omega: Any) -> tuple[Any, Any]:
        """(ω₂, f): propeller speed [rad/s] and thrust [N] of the rotor speed ω₁ [rad/s]."""
        w2 = self._eval(self._one("gear"), xp, {"omega": omega})
        return w2, self._eval(self._one("thrust"), xp, {"omega_prop": w2})

    def slot_values(self, slot: str, xp: Any, inputs: Mapping[str, Any]) -> dict[str, Any]:
        """Each active term of ``slot`` evaluated at ``inputs`` (label -> value), in order.

        Parameters
        ----------
        slot : str
        xp : namespace
            ``xp.MATH`` for floats, ``xp.NUMPY`` for arrays.
        inputs : mapping
            The slot's inputs by name (:data:`aeropend_sim.components.base.SLOT_INPUTS`).
        """
        return {t.label: self._eval(t, xp, inputs) for t in self.slots.get(slot, ())}

    def _sum_values(self, slot: str, xp: Any, inputs: Mapping[str, Any], first: Any = None) -> Any:
        total = first
        for v in self.slot_values(slot, xp, inputs).values():
            total = v if total is None else total + v
        return 0.0 if total is None else total

    def point(self, xp: Any, x: Any, u: Any) -> dict[str, Any]:
        """Every signal of the chain at state ``x`` (rows of shape (…, n) or a sequence of the
        :attr:`states`; the chain's five also do, the effects' states then at their initial values)
        and input ``u``.

        Returns ``{"tau", "tau_e", drive name, "r_a", "i_a", "omega", "omega_prop", "thrust",
        "theta", "theta_dot", "u", "tau_f"}`` and each effect state by name; ``i_a`` is the
        algebraic current when the armature is quasi-static, 0 without an armature; ``r_a`` the
        armature resistance (absent without an armature).
        """
        n = self.states.size
        if isinstance(x, np.ndarray):
            x = self.states.complete(x, "state")
            xs = [x[..., k] for k in range(n)]
        else:
            xs = self.states.whole(x)
        theta, theta_dot, i_a, omega, tau_f = xs[:N_CHAIN]
        extra = {st.name: v for st, v in zip(self.states.extra, xs[N_CHAIN:], strict=True)}
        tau = tau_f if self.lag else u
        tau_e = self.duty_chain(xp, tau)
        q = self._eval(self._one("drive"), xp, {"tau": tau_e})
        out = {"u": u, "tau_f": tau_f, "tau": tau, "tau_e": tau_e, self.drive_name: q, **extra}
        if not self.armature:
            i_a = 0.0 * omega
        else:
            out["r_a"] = r_a = self._eval(self._one("resistance"), xp, extra)
            if not self.dynamic_current:
                i_a = self._sum_values("armature", xp, {"omega": omega}, first=q) / r_a
        w2, f = self.propeller(xp, omega)
        out.update({"i_a": i_a, "omega": omega, "omega_prop": w2, "thrust": f, "theta": theta,
                    "theta_dot": theta_dot})
        return out

    # ------------------------------------------------------------------ linearisation
    def _d(self, slot: str, name: str, vals: Mapping[str, Any], skip_sign: bool = False) -> float:
        """Σ ∂term/∂``name`` over the slot's active terms at ``vals`` (scalars)."""
        return sum((t.partial(MATH, name, vals) for t in self.slots.get(slot, ())
                    if not (skip_sign and t.regularised_sign)), 0.0)

    def jacobian(self, x: Any, u: float, dry_friction: bool = True) -> tuple[np.ndarray, np.ndarray]:
        """A = ∂f/∂x (n×n), B = ∂f/∂u (n×1) at (x, u), n = :attr:`states` ``.size``: the chain's
        entries by the chain rule over the terms' partials, those of the effects' own states
        (their rows, and the chain's dependence on them) by central differences of :attr:`rhs`
        (step :data:`~aeropend_sim.components.base.FD_STEP`·max(1, |x|)).

        ``dry_friction=False`` leaves out terms whose slope comes from a regularised sign (see
        :attr:`aeropend_sim.components.base.Term.regularised_sign`).
        """
        n = self.states.size
        A = np.zeros((n, n))
        B = np.zeros((n, 1))
        x = self.states.whole(x)
        p = self.point(MATH, x, float(u))
        vals = self._with(p)
        # d(drive)/d(source), source = τ_f (lag) or u
        dtau = 1.0
        tau = p["tau"]
        for term in self.slots.get("duty", ()):
            v = self._with({"tau": tau})
            dtau *= term.partial(MATH, "tau", v)
            tau = term(MATH, v)
        dq = self._one("drive").partial(MATH, "tau", self._with({"tau": p["tau_e"]})) * dtau
        b = np.zeros(n)
        if self.lag:
            lag = self._one("lag")
            A[TAU_F, TAU_F] = lag.partial(MATH, "tau_f", vals)
            B[TAU_F, 0] = lag.partial(MATH, "u", vals)
        if self.armature:
            r, la, jm = p["r_a"], self.values["motor.L_a"], self.values["motor.J_m"]
            da_dw = self._d("armature", "omega", vals)
            dr_di = self._d("rotor_torque", "i_a", vals)
            dr_dw = self._d("rotor_torque", "omega", vals)
            if self.dynamic_current:
                A[I_A, I_A] = -r / la
                A[I_A, OMEGA] = da_dw / la
                b[I_A] = dq / la
                A[OMEGA, I_A] = dr_di / jm
                A[OMEGA, OMEGA] = dr_dw / jm
            else:
                A[OMEGA, OMEGA] = (dr_dw + dr_di * da_dw / r) / jm
                b[OMEGA] = dr_di * (dq / r) / jm
        else:
            A[OMEGA, OMEGA] = self._d("rotor_response", "omega", vals)
            b[OMEGA] = self._d("rotor_response", "omega_sp", vals) * dq
        dw2 = self._one("gear").partial(MATH, "omega", vals)
        df = self._one("thrust").partial(MATH, "omega_prop", vals)
        A[THETA, THETA_DOT] = 1.0
        A[THETA_DOT, THETA] = self._d("rod", "theta", vals)
        A[THETA_DOT, THETA_DOT] = self._d("rod", "theta_dot", vals, skip_sign=not dry_friction)
        A[THETA_DOT, OMEGA] = self._d("rod", "thrust", vals) * df * dw2
        if self.lag:
            A[:, TAU_F] += b
        else:
            B[:, 0] += b
        if n > N_CHAIN:
            self._effect_state_jacobian(A, B, x, float(u))
        return A, B

    def _effect_state_jacobian(self, A: np.ndarray, B: np.ndarray, x: list[float], u: float) -> None:
        """Fill the effects' states' rows and columns of A and rows of B by central differences."""
        def diff(k: int | None) -> np.ndarray:
            h = FD_STEP * max(1.0, abs(x[k] if k is not None else u))
            hi, lo = list(x), list(x)
            if k is None:
                return (np.array(self.rhs(0.0, x, u + h)) - np.array(self.rhs(0.0, x, u - h))) / (2.0 * h)
            hi[k] += h
            lo[k] -= h
            return (np.array(self.rhs(0.0, hi, u)) - np.array(self.rhs(0.0, lo, u))) / (2.0 * h)

        extra = range(N_CHAIN, self.states.size)
        for k in extra:
            A[:, k] = diff(k)
        for j in range(N_CHAIN):
            A[list(extra), j] = diff(j)[list(extra)]
        B[list(extra), 0] = diff(None)[list(extra)]

    # ------------------------------------------------------------------ steady state
    def duty_for_drive(self, q: float) -> float:
        """Duty cycle τ (before the lag, at steady state) whose drive quantity is ``q`` (≥ 0).

        Inverts the drive map and the duty terms in reverse order; τ = 0 for q ≤ 0. The result may
        exceed 1 (the caller checks the range).
        """
        tau = float(self._one("drive").inverse(MATH, q, *self._params_of(self._one("drive"))))
        for term in reversed(self.slots.get("duty", ())):
            tau = float(term.inverse(MATH, tau, *self._params_of(term)))
        return tau

    def _params_of(self, term: Term) -> tuple[float, ...]:
        """The term's parameters' effective values in its order (looked up once per term)."""
        got = self._params.get(id(term))
        if got is None:
            got = self._params[id(term)] = tuple(self.by_name[a] for a in term.param_names)
        return got

    def thrust_to_hold(self, theta: float) -> float:
        """Thrust f [N] that holds the rod at rest at angle θ [rad] (contact terms left out).

        The rod's terms are linear in the thrust (the thrust torque):
        f = −Σ(rod terms without f)/Σ∂/∂f at (θ, θ̇ = 0).
        """
        vals = self._with({"theta": theta, "theta_dot": 0.0, "thrust": 0.0})
        held = [t for t in self.slots["rod"] if "thrust" not in t.inputs and not t.contact]
        rest = sum((t(MATH, vals) for t in held), 0.0)
        return -rest / self._d("rod", "thrust", vals)

    def drive_for_thrust(self, f: float) -> tuple[float, float, float]:
        """Steady current i_a [A], rotor speed ω₁ [rad/s] and drive quantity q that deliver thrust f ≥ 0 [N].

        ω₂ = thrust⁻¹(f), ω₁ = gear⁻¹(ω₂), then (DC motor) i_a = −Σ(torques without i_a)/Σ∂/∂i_a
        (the rotor torques are linear in the current) and q = v_a = R_a·i_a − Σ armature terms, or
        (ESC) i_a = 0 and q = ω_ss = rotor-response⁻¹(ω₁). The drive quantity is the family's:
        armature voltage [V] or the ESC's rotor-speed set-point [rad/s] (:attr:`drive_name`).
        """
        thrust, gear, load_terms, torque, r_rest = self._steady_chain
        w2 = thrust.inverse(MATH, f, *self._params_of(thrust))
        w1 = gear.inverse(MATH, w2, *self._params_of(gear))
        if self.armature:
            at = {"omega": w1, "i_a": 0.0}
            load = None
            for t in load_terms:
                v = self._eval(t, MATH, at)
                load = v if load is None else load + v
            i = -(load if load is not None else 0.0) / sum((self._partial(t, "i_a", at) for t in torque), 0.0)
            q = r_rest * i - self._sum_values("armature", MATH, {"omega": w1})
        else:
            i = 0.0
            term = self._one("rotor_response")
            q = term.inverse(MATH, w1, *self._params_of(term))
        return float(i), float(w1), float(q)

    @cached_property
    def _steady_chain(self) -> tuple[Term, Term, tuple[Term, ...], tuple[Term, ...], float]:
        """What :meth:`drive_for_thrust` reads at every call, looked up once: the thrust and gear
        terms, the rotor torques without and all with the armature current, and the armature
        resistance at rest (NaN without an armature)."""
        torque = self.slots.get("rotor_torque", ())
        return (self._one("thrust"), self._one("gear"), tuple(t for t in torque if "i_a" not in t.inputs),
                torque, self._resistance_at_rest() if self.armature else math.nan)

    def _resistance_at_rest(self) -> float:
        """Armature resistance [Ω] with the effects' states at their initial values."""
        rest = {st.name: st.initial for st in self.states.extra}
        return float(self._eval(self._one("resistance"), MATH, rest))

    def steady_state(self, theta: float) -> tuple[list[float], float]:
        """State (θ, 0, i_a, ω₁, q, <effect states>) with θ̈ = 0 and ω̇₁ = 0 at angle θ, and the
        drive quantity q.

        Contact terms (end stops) are left out: the state is the one the thrust holds
        (:meth:`thrust_to_hold`, then :meth:`drive_for_thrust`). The τ_f entry is left to the
        caller (τ). The effects' own states are held at their initial values (a heated winding at
        ambient temperature: the chain's steady state on a time scale where they have not moved).
        """
        i, w1, q = self.drive_for_thrust(self.thrust_to_hold(theta))
        return [theta, 0.0, i, w1, 0.0, *(st.initial for st in self.states.extra)], q
