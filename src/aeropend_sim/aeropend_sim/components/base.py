"""Declaration classes of the plant's components and effects (one declaration per module).

Every piece of the plant is declared once, in its own module under ``components/``:

* a :class:`Component` is a part every rig of its actuator family has (the drive, the motor, the
  gearbox, the propeller's thrust, the rod, the sensors); an actuator family is a
  :class:`Family`, the component that fixes which drive quantity the motor receives;
* an :class:`Effect` is an optional piece of physics a rig file switches on and off in its
  ``effects:`` section (a dead zone, rotor brush friction, end stops, ...).

Both hold their :class:`Param` declarations (key ``"section.name"``, unit, meaning, sign, the value
that means "not modelled", grey-box fit bounds), their physics as :class:`Term` objects (plain
functions of floats or arrays written against an ``xp`` namespace, :mod:`.xp`) and what the gap
diagnosis needs to know about them (:class:`Diagnosis`, plain data). Modules expose their
declaration as a module-level ``COMPONENT``, ``FAMILY`` or ``EFFECT``;
:mod:`aeropend_sim.components.registry` finds them, so adding an effect is one new module.

Where a term sits in the plant is its *slot* (:data:`SLOTS`); what it reads are *inputs*
(:data:`INPUTS`) and parameters, both named by the term function's arguments.
"""

from __future__ import annotations

import inspect
import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Any

from aeropend_sim.components.states import State

#: Rig-file sections, in file order.
SECTIONS: tuple[str, ...] = ("actuator", "motor", "thrust", "pendulum", "sensors")

#: Component kinds (the ``part`` of a declaration), in the order of the signal chain.
PARTS: tuple[str, ...] = ("actuator", "rotor", "thrust", "pendulum", "sensors")

#: Slots of the plant, in the order of the signal chain: what a term in each slot returns and how
#: the slot's terms combine (:mod:`aeropend_sim.components.assembly`).
SLOTS: dict[str, str] = {
    "lag": "τ̇_f [1/s], the derivative of the actuator-lag state x[4] (one term)",
    "duty": "the duty cycle after a transform (dead zone) [1]; terms are applied in order",
    "drive": "the drive quantity of the family (v_a [V] or ω_sp [rad/s]) of the duty cycle τ_e; "
             "the active term of highest order is the map",
    "armature": "voltage terms of L_a·di_a/dt = v_a − R_a·i_a + Σ [V] (DC motor), summed in order",
    "rotor_torque": "torques on the rotor [N·m] (DC motor), summed in order: J_m·ω̇₁ = Σ",
    "rotor_response": "ω̇₁ [rad/s²] of a speed-controlled rotor (ESC), one term",
    "gear": "propeller speed ω₂ [rad/s] of the rotor speed ω₁ (one term)",
    "thrust": "thrust f [N] of the propeller speed ω₂ (one term)",
    "rod": "terms of θ̈ [rad/s²], summed in order",
    "resistance": "armature resistance [Ω] of the armature circuit (DC motor); the active term of "
                  "highest order is the resistance (R_a, or R_a(T_m) of a heated winding)",
    "rate": "the time derivative of an effect's own state (Term.state names it), summed in order",
}

#: Slots whose terms are summed (an absent term, one whose parameters hold their absent values,
#: adds an exact 0.0: :mod:`aeropend_sim.compiled` keeps such terms in place instead of recompiling).
SUM_SLOTS: tuple[str, ...] = ("armature", "rotor_torque", "rod")

#: Inputs a term in each slot may read (its function's arguments besides ``xp`` and parameters).
SLOT_INPUTS: dict[str, tuple[str, ...]] = {
    "lag": ("u", "tau_f"),
    "duty": ("tau",),
    "drive": ("tau",),
    "armature": ("omega",),
    "rotor_torque": ("i_a", "omega"),
    "rotor_response": ("omega_sp", "omega"),
    "gear": ("omega",),
    "thrust": ("omega_prop",),
    "rod": ("theta", "theta_dot", "thrust"),
    "resistance": (),
    "rate": ("u", "i_a", "omega", "theta", "theta_dot"),
}

#: Inputs a term may read (by argument name), with unit and meaning.
INPUTS: dict[str, str] = {
    "u": "[1] duty cycle reaching the actuator (after the input delay)",
    "tau_f": "[1] actuator-lag state x[4]",
    "tau": "[1] duty cycle in the duty chain (after the lag, then after each duty transform)",
    "v_a": "[V] armature voltage (drive quantity of the voltage-driven families)",
    "omega_sp": "[rad/s] rotor speed set-point of an ESC (drive quantity of the esc family)",
    "i_a": "[A] armature current x[2]",
    "omega": "[rad/s] rotor speed ω₁ x[3]",
    "omega_prop": "[rad/s] propeller speed ω₂ = ω₁/n",
    "thrust": "[N] propeller thrust f",
    "theta": "[rad] rod angle x[0]",
    "theta_dot": "[rad/s] rod angular velocity x[1]",
}

#: Why a DC motor's rotor has no ``rotor_response`` slot (said by both voltage-driven families).
DC_ROTOR = ("a DC motor's rotor follows its torque balance J_m·ω̇₁ = K_t·i_a − ..., not a speed set-point "
            "of its own controller")

#: Relative step of the documented finite-difference fallback of a term's partial derivative:
#: h = FD_STEP·max(1, |input|), central difference (used only where a term gives no ``partials``).
FD_STEP = 1e-6


@dataclass(frozen=True)
class FitBounds:
    """Grey-box fit bounds of a parameter (read by :mod:`aeropend_ident.greybox.fit`).

    Attributes
    ----------
    lower, upper : float or None
        Bounds in the parameter's unit; ``None``: relative to the starting value (×1e-3, ×1e3).
    log : bool
        Fitted as log(value) (strictly positive parameters).
    scale : float or None
        Parameter units per optimiser unit of a linearly fitted parameter (about a typical change);
        ``None``: the fit picks one from the start value and the bounds.
    """

    lower: float | None
    upper: float | None
    log: bool
    scale: float | None = None


@dataclass(frozen=True)
class Param:
    """One physical parameter, declared by the component or effect it belongs to.

    Attributes
    ----------
    key : str
        ``"section.name"`` with section in :data:`SECTIONS`, e.g. ``"motor.B_m"``; ``name`` is
        also the argument name that term functions use, so it is unique over the registry.
    unit : str
        SI unit as written in rig files (``"N*m*s/rad"``).
    doc : str
        Physical meaning (one line).
    sign : str
        ``"positive"`` (> 0), ``"nonneg"`` (≥ 0) or ``""`` (any sign). Checked whenever its owner is
        active; an inactive owner's parameter may also hold its ``absent`` value.
    below : float
        Strict upper limit (a fraction < 1); ``inf`` when none.
    absent : float or None
        The value used when a rig file does not give the parameter: the value that means "not
        modelled" (T_c = 0: no brush friction), or for a ``setting`` its default. ``None``: a
        required parameter of a component (a rig file without it is refused, naming the key).
    setting : bool
        A numerical setting with a documented default (a regularisation width, an RMS reference)
        rather than a physical quantity that can be absent.
    fit : FitBounds or None
        Grey-box fit bounds where the fit has physical ones (``None``: from the sign).
    relative_truth : tuple of (float, float)
        Factor intervals of the nominal value that the blind benchmarks draw a wrong value of this
        parameter from (one interval is drawn, then a factor uniformly inside it); ``()``: none.
    symbol : str
        Symbol for tables (default: the name).
    typical : float or None
        A value typical of a lab's rig: the clearly marked starting value ``rig new`` writes for a
        parameter to be fitted (``None``: the absent value, or none).
    measure : str
        How a lab states or measures it (one line): what ``rig fit`` says to do when recordings
        cannot determine it.
    """

    key: str
    unit: str
    doc: str
    sign: str = ""
    below: float = math.inf
    absent: float | None = None
    setting: bool = False
    fit: FitBounds | None = None
    relative_truth: tuple[tuple[float, float], ...] = ()
    symbol: str = ""
    typical: float | None = None
    measure: str = ""

    def __post_init__(self) -> None:
        section, dot, name = self.key.partition(".")
        if not dot or section not in SECTIONS or not name.isidentifier():
            raise ValueError(f"Param key {self.key!r}: expected 'section.name' with section in {SECTIONS}")
        if self.sign not in ("", "positive", "nonneg"):
            raise ValueError(f"Param {self.key}: sign {self.sign!r}; expected '', 'positive' or 'nonneg'")

    @property
    def section(self) -> str:
        """Rig-file section (``"motor"``)."""
        return self.key.partition(".")[0]

    @property
    def name(self) -> str:
        """Name inside the section, also the term-function argument name (``"B_m"``)."""
        return self.key.partition(".")[2]

    @property
    def required(self) -> bool:
        """True when a rig file must give it (a component parameter without an absent value)."""
        return self.absent is None

    def violation(self, value: float, active: bool = True) -> str | None:
        """Why ``value`` is not valid for this parameter, or None.

        Parameters
        ----------
        value : float
        active : bool
            Whether the owner (component or effect) is active. An inactive owner's parameter may
            also hold its ``absent`` value (e.g. L_a = 0 while the armature is quasi-static).
        """
        if not active and self.absent is not None and value == self.absent:
            return None
        if active and value == self.absent and not math.isfinite(value):
            return None  # an infinite absent value (no end stop on that side) is valid when on
        if not math.isfinite(value):
            return f"{self.key} = {value!r} is not finite"
        if self.sign == "positive" and not value > 0.0:
            return f"{self.key} = {value!r} must be > 0 ({self.doc})"
        if self.sign == "nonneg" and value < 0.0:
            return f"{self.key} = {value!r} must be >= 0 ({self.doc})"
        if not value < self.below:
            return f"{self.key} = {value!r} must be < {self.below:g} ({self.doc})"
        return None


def _signature(fn: Callable[..., Any]) -> tuple[str, ...]:
    names = tuple(inspect.signature(fn).parameters)
    if not names or names[0] != "xp":
        raise ValueError(f"term function {fn.__qualname__}: the first argument must be 'xp' (got {names})")
    return names[1:]


@dataclass(frozen=True)
class Term:
    """One contribution to the plant's equations: a plain function in array-namespace style.

    ``fn(xp, <inputs>, <params>)`` returns the contribution in the slot's unit; its argument
    names say what it reads: inputs from :data:`INPUTS`, parameters by :attr:`Param.name`.
    It must use only the operations of :mod:`aeropend_sim.components.xp` (through ``xp``) and
    arithmetic, so the same function runs on floats (``xp.MATH``), arrays (``xp.NUMPY``) and a
    compiled backend.

    Attributes
    ----------
    slot : str
        Where it acts (:data:`SLOTS`).
    order : int
        Position in the slot: the order of floating-point summation (sum slots), of application
        (``duty``) or the precedence of a map (``drive``: the highest active order wins).
    fn : callable
        The contribution.
    label : str
        Short formula for tables and equation-error groups, e.g. ``"−B_m·ω₁"``.
    partials : mapping
        Input name -> ∂fn/∂input with the same signature as ``fn``. An input without an entry
        is differentiated by a central difference of ``fn`` (step :data:`FD_STEP`·max(1, |x|)).
    inverse : callable or None
        For ``duty``, ``drive`` and ``thrust`` terms: ``inverse(xp, y, <params>)``, the input that
        gives output ``y`` (steady-state design: :meth:`aeropend_sim.model.PlantModel.equilibrium`).
    regularised_sign : bool
        The term's slope comes from the tanh regularisation of a sign (rod dry friction):
        ``PlantModel.jacobian(..., dry_friction=False)`` leaves it out.
    contact : bool
        A contact (constraint) force, e.g. an end stop: left out of the thrust-held steady state
        (:meth:`aeropend_sim.model.PlantModel.equilibrium` is the angle the thrust holds).
    state : str or None
        For a ``rate`` term: the state (declared by its part, :attr:`Part.states`) whose time
        derivative it gives.
    states : tuple of str
        The part's own states the term reads (argument names; inputs besides the slot's).
    """

    slot: str
    order: int
    fn: Callable[..., Any]
    label: str
    partials: Mapping[str, Callable[..., Any]] = field(default_factory=dict)
    inverse: Callable[..., Any] | None = None
    regularised_sign: bool = False
    contact: bool = False
    state: str | None = None
    states: tuple[str, ...] = ()
    arguments: tuple[str, ...] = field(init=False, compare=False)
    inputs: tuple[str, ...] = field(init=False, compare=False)
    param_names: tuple[str, ...] = field(init=False, compare=False)

    def __post_init__(self) -> None:
        if self.slot not in SLOTS:
            raise ValueError(f"term {self.label!r}: slot {self.slot!r}; expected one of {list(SLOTS)}")
        args = _signature(self.fn)
        # the argument names after ``xp``; the inputs (INPUTS) and the parameters (by Param.name) among them
        object.__setattr__(self, "arguments", args)
        if (self.slot == "rate") != (self.state is not None):
            raise ValueError(f"term {self.label!r}: a rate term names the state it drives (state=...), and "
                             "only a rate term does")
        object.__setattr__(self, "inputs", tuple(a for a in args if a in INPUTS or a in self.states))
        object.__setattr__(self, "param_names", tuple(a for a in args if a not in self.inputs))
        wrong = [a for a in args if a in INPUTS and a not in SLOT_INPUTS[self.slot]]
        if wrong:
            raise ValueError(f"term {self.label!r} in slot {self.slot!r} reads {wrong}; a {self.slot} term "
                             f"may read {SLOT_INPUTS[self.slot]}")
        for name, d in self.partials.items():
            if name not in INPUTS or name not in args:
                raise ValueError(f"term {self.label!r}: partial for {name!r}, which is not one of its inputs")
            if _signature(d) != args:
                raise ValueError(f"term {self.label!r}: ∂/∂{name} must take the same arguments as the term")
        object.__setattr__(self, "partials", MappingProxyType(dict(self.partials)))

    def __call__(self, xp: Any, values: Mapping[str, Any]) -> Any:
        """Evaluate with every argument taken from ``values`` (inputs and parameters by name)."""
        return self.fn(xp, *(values[a] for a in self.arguments))

    def partial(self, xp: Any, name: str, values: Mapping[str, Any]) -> Any:
        """∂term/∂``name`` at ``values``: the declared partial, else a central difference of ``fn``."""
        if name not in self.inputs:
            return 0.0
        d = self.partials.get(name)
        if d is not None:
            return d(xp, *(values[a] for a in self.arguments))
        x = values[name]
        h = FD_STEP * max(1.0, abs(x))
        hi, lo = dict(values), dict(values)
        hi[name], lo[name] = x + h, x - h
        return (self(xp, hi) - self(xp, lo)) / (2.0 * h)


@dataclass(frozen=True)
class Search:
    """How the gap diagnosis searches one parameter of a hypothesis on a rig and its recordings.

    The range is physics of the rig: it is derived from the nominal rig and the recording's scales
    (the largest recorded duty cycle, the drive and rotor speed there, ...), not from the nominal
    value alone, so an effect the rig omits is found at any plausible size.

    Attributes
    ----------
    name : str
        The diagnosis parameter (an entry of :attr:`Diagnosis.params`).
    unit : str
        SI unit.
    limits : (float, float)
        Physically valid values (the diagnosis refuses a value outside).
    target : str
        Where the value ends up: a rig parameter ``"section.name"`` or ``"measurement.<attr>"``
        (the angle-sensor transform of the diagnosis).
    doc : str
        Meaning (one line).
    range : callable
        ``range(ctx) -> (lower, upper, off, probe)``: the search interval, the value at which the
        hypothesis is absent (the nominal rig's) and a typical magnitude. ``ctx`` is the
        diagnosis' context of the nominal rig and the data
        (:class:`aeropend_ident.gap.effects.EffectContext`):
        ``ctx.rig``, ``ctx.duty_max`` (largest recorded duty), ``ctx.drive_max`` (drive quantity
        there), ``ctx.omega_max`` (steady rotor speed there), ``ctx.omega_ref`` (steady propeller
        speed at the median duty), ``ctx.theta_hi`` (0.995 quantile of the recorded angle, model
        frame) and ``ctx.rotor_torque(omega, without=...)`` (the nominal rig's net rotor torque at
        ``drive_max`` and speed ω without one effect's terms).
    range_doc : str
        The range in words (docs tables).
    log : bool
        Searched as log(value) (strictly positive parameters).
    held : bool
        Held at the rig's value unless the diagnosis frees it, where its validation data say the
        free value predicts better (the dry friction's onset width v_ε,
        :func:`aeropend_ident.gap.which.fitting.fit_effects`); a value not given keeps the rig's.
    """

    name: str
    unit: str
    limits: tuple[float, float]
    target: str
    doc: str
    range: Callable[[Any], tuple[float, float, float, float]] = field(repr=False, compare=False)
    range_doc: str = ""
    log: bool = False
    held: bool = False


#: Limits of a strictly positive searched parameter.
POSITIVE = (1e-300, math.inf)


def scaled(value: float, lo: float, hi: float, probe: float) -> tuple[float, float, float, float]:
    """A :attr:`Search.range` of a parameter the rig states: ``value`` scaled by [lo, hi], absent at
    ``value``, probe ``value·probe``."""
    return value * lo, value * hi, value, value * probe


def load_range(nominal: float, on: bool, halving: float, probe: float) -> tuple[float, float, float, float]:
    """A :attr:`Search.range` of a rotor load coefficient (B_m, K_d, T_c): up to 3× the value that
    would halve the steady rotor speed at the largest recorded duty (``halving``) and 0.05–20× a
    nominal value the rig has (``on``); probe ``probe``·halving when it has none."""
    if on and nominal > 0.0:
        return min(0.05 * nominal, 1e-3 * halving), max(20.0 * nominal, 3.0 * halving), nominal, 1.3 * nominal
    return 1e-3 * halving, 3.0 * halving, 0.0, probe * halving


@dataclass(frozen=True)
class Diagnosis:
    """What the gap diagnosis needs to know about one hypothesis (plain data, read by
    :mod:`aeropend_ident.gap`): an effect that may be missing, or a parameter that may be wrong.

    Attributes
    ----------
    name : str
        Catalog key (``"rotor_friction"``).
    subsystem : str
        ``"actuator" | "electrical" | "motor" | "aerodynamic" | "pendulum" | "sensor"``.
    description : str
        What it is, with its equation.
    params : tuple of str
        Names of the fitted parameters, in order (a rig parameter's name, or a quantity of the
        diagnosis itself such as a voltage drop ``V_drop``).
    reveals : tuple of str
        Channels that must be recorded (besides the duty cycle) to identify it.
    sindy_terms : mapping
        Discrepancy-SINDy term group: equation (``"theta_dot"``, ``"i_a"``, ``"omega_rotor"``,
        ``"v_a"``) -> named candidate columns.
    confusable_with : tuple of str
        Hypotheses with a similar signature on the channels in ``reveals``.
    truth : mapping
        Absolute truth ranges the blind benchmarks draw from, parameter name -> intervals
        (parameters with :attr:`Param.relative_truth` take those instead).
    kind : str
        ``"model"``, ``"measurement"``, ``"direct"`` or ``"drift"`` (see the gap catalog).
    screened : bool
        Part of the discrepancy-SINDy screening.
    exclusive_with, nests, refines : tuple of str
        Catalog relations (never together; contains as a special case; an operating-point
        refinement of).
    order : int
        Position in the gap catalog (the order the diagnosis lists, screens and applies its
        hypotheses: along the signal chain, a drive error before the motor's).
    search : tuple of Search
        How each parameter in :attr:`params` is searched (same names, same order).
    apply : callable or None
        ``apply(rig, values) -> rig``: the nominal rig with the hypothesis in place at the physical
        ``values`` (``{name: value}``), through the rig's ``with_params``/``with_effects``; raises
        ``ValueError`` for values the rig cannot take. ``None``: the rig is unchanged (a
        measurement transform, or a property detected from the data).
    timing : bool
        Changes when the thrust follows the command (a lag, a delay, a slow rotor): the diagnosis
        confirms it by a grey-box fit whenever the recorded response leads or lags the simulated one.
    drift_sigma : float
        For a quantity that changes between sessions of one rig (air density, a re-mounted
        propeller, a battery's charge): the prior standard deviation of its session-to-session log
        change (0.15 ≈ ±15 %), with the physical reason in the declaring module; 0: not drift-prone.
        Read by :mod:`aeropend_ident.gap.drift` (the parameter is the hypothesis' first).
    power_law : tuple
        ``(level, exponent, exponent₀)`` for a law level·|ω|^exponent whose two parameters the data
        confound (the thrust law, K_q in N·(s/rad)^α: log K_q moves by −ln ω per unit of α). Its level
        is compared between sessions as the hypothesis it nests (``nests[0]``, whose law has the
        exponent exponent₀) at the recordings' reference speed ω_ref, level·ω_ref^(exponent −
        exponent₀): the level the data pin, in one unit whatever the fitted exponents. Read by
        :func:`aeropend_ident.gap.sessions.drift_rows`; empty: none.
    """

    name: str
    subsystem: str
    description: str
    params: tuple[str, ...]
    reveals: tuple[str, ...]
    sindy_terms: Mapping[str, tuple[str, ...]] = field(default_factory=dict)
    confusable_with: tuple[str, ...] = ()
    truth: Mapping[str, tuple[tuple[float, float], ...]] = field(default_factory=dict)
    kind: str = "model"
    screened: bool = True
    exclusive_with: tuple[str, ...] = ()
    nests: tuple[str, ...] = ()
    refines: tuple[str, ...] = ()
    order: int = 0
    search: tuple[Search, ...] = ()
    apply: Callable[[Any, Mapping[str, float]], Any] | None = field(default=None, compare=False)
    timing: bool = False
    drift_sigma: float = 0.0
    power_law: tuple[str, str, float] | tuple[()] = ()

    def __post_init__(self) -> None:
        names = tuple(s.name for s in self.search)
        if self.search and names != self.params:
            raise ValueError(f"diagnosis {self.name!r}: search {names} must name its params {self.params} "
                             "in order")
        for p in self.truth:
            if p not in self.params:
                raise ValueError(f"diagnosis {self.name!r}: truth range for {p!r}, not one of {self.params}")
        if self.power_law and (not self.nests or any(p not in self.params for p in self.power_law[:2])):
            raise ValueError(f"diagnosis {self.name!r}: power_law {self.power_law} needs two of its params "
                             f"{self.params} and a nested hypothesis")


@dataclass(frozen=True)
class Part:
    """Common fields of components and effects.

    Attributes
    ----------
    name : str
        Unique name (an effect's is also its switch in the rig file's ``effects:`` section).
    part : str
        The component kind it belongs to (:data:`PARTS`).
    label : str
        Short title for tables.
    description : str
        One line: what it is, with its equation.
    order : int
        Listing order (tables, registry lists); effects are also applied in this order.
    params : tuple of Param
    terms : tuple of Term
    diagnoses : tuple of Diagnosis
    families : tuple of str or None
        Actuator families it belongs to; ``None``: every family that has the slots it needs
        (:attr:`slots`) and does not refuse it (:attr:`Family.refuses`), so a family written later
        gets it without an edit here.
    why_not : str
        Why it does not apply to the other families (said when a rig file asks for it anyway).
    needs : tuple of str
        Slots it acts on besides its terms' (the armature inductance acts through the armature
        equation itself): a family that lacks one (:attr:`Family.lacks`) has not this part.
    check : callable or None
        ``check(values) -> message or None``: a cross-parameter constraint (θ_min < θ_max), given
        ``{key: value}`` of the rig's parameters.
    states : tuple of State
        States of its own (an effect's: :mod:`aeropend_sim.components.states`), each driven by one
        of its ``rate`` terms; a rig on which it acts has them after the chain's.
    """

    name: str
    part: str
    label: str
    description: str
    order: int
    params: tuple[Param, ...] = ()
    terms: tuple[Term, ...] = ()
    diagnoses: tuple[Diagnosis, ...] = ()
    families: tuple[str, ...] | None = None
    why_not: str = ""
    check: Callable[[Mapping[str, float]], str | None] | None = field(default=None, compare=False)
    needs: tuple[str, ...] = ()
    states: tuple[State, ...] = ()

    def __post_init__(self) -> None:
        own = {st.name for st in self.states}
        if any(st.variable != st.name for st in self.states):
            raise ValueError(f"{self.name}: a part's state is read by its name (no separate variable)")
        for term in self.terms:
            if not set(term.states) <= own or (term.state is not None and term.state not in own):
                raise ValueError(f"{self.name}: term {term.label!r} reads or drives a state it does not "
                                 f"declare (its states: {sorted(own)})")
        undriven = sorted(own - {t.state for t in self.terms})
        if undriven:
            raise ValueError(f"{self.name}: state(s) {undriven} have no rate term")
        if self.part not in PARTS:
            raise ValueError(f"{self.name}: part {self.part!r}; expected one of {PARTS}")
        bad = [n for n in self.needs if n not in SLOTS]
        if bad:
            raise ValueError(f"{self.name}: needs slot(s) {bad}; expected some of {list(SLOTS)}")

    @property
    def slots(self) -> frozenset[str]:
        """Slots it acts in: its terms' and those it :attr:`needs`."""
        return frozenset(t.slot for t in self.terms) | frozenset(self.needs)

    def applies_to(self, family: Family) -> str | None:
        """None if it belongs on a rig of ``family``, else the reason why not."""
        if self.families is not None and family.name not in self.families:
            fams = " and ".join(self.families)
            return self.why_not or f"{self.name} is part of {fams} rigs only"
        if self.name in family.refuses:
            return family.refuses[self.name]
        for slot in sorted(self.slots):
            if slot in family.lacks:
                return (f"it acts on the {slot} slot, which the {family.name} family has not: "
                        f"{family.lacks[slot]}")
        return None


@dataclass(frozen=True)
class Component(Part):
    """A non-optional part of the plant (active on every rig of the families it belongs to).

    Attributes (beyond :class:`Part`)
    ----------
    geometry : tuple of Param
        Rig-file inputs the loader derives this component's parameters from (the rod's mass and
        lengths, :attr:`derive`); not stored on the rig.
    derive : callable or None
        ``derive(given) -> {key: (value, how)}``: the parameters computed from the ``geometry``
        inputs given (``{key: value}``), each with a one-line account of how.
    """

    geometry: tuple[Param, ...] = ()
    derive: Callable[[Mapping[str, float]], dict[str, tuple[float, str]]] | None = field(default=None,
                                                                                        compare=False)


@dataclass(frozen=True)
class Family(Component):
    """An actuator family (``actuator.family`` in the rig file): how the command moves the rotor.

    Attributes (beyond :class:`Component`)
    ----------
    drive : str
        The drive quantity its ``drive`` slot returns (``"v_a"`` or ``"omega_sp"``, :data:`INPUTS`).
    lacks : mapping
        Slots this family does not have, each with the physical reason (an effect acting there
        is refused on a rig of this family with that reason).
    channels : tuple of str
        The measured channels a simulation of this family produces (no armature channels on an
        ESC: absent, not zeros).
    refuses : mapping
        Effects it has not although it has their slots, each with the physical reason (an ESC's
        idle throttle is its dead zone: a second ``dead_zone`` could not be told from it).
    usual_effects : tuple of str
        Effects a lab's rig of this family usually has: ``rig new`` marks their parameters to be
        fitted (the others are written commented out, not modelled).
    """

    drive: str = "v_a"
    lacks: Mapping[str, str] = field(default_factory=dict)
    channels: tuple[str, ...] = ("theta", "theta_dot", "omega_rotor", "omega_prop", "i_a", "v_a")
    refuses: Mapping[str, str] = field(default_factory=dict)
    usual_effects: tuple[str, ...] = ()


@dataclass(frozen=True)
class Effect(Part):
    """An optional piece of physics, switched in the rig file's ``effects:`` section.

    Attributes (beyond :class:`Part`)
    ----------
    modes : (str, str) or None
        For a switch that takes a mode instead of true/false: (on mode, off mode), e.g.
        ``("dynamic", "quasi_static")``.
    legacy_switch : str or None
        The pre-issue-35 switch that turned it on together with others (``"viscous_friction"``
        for both the rod's c/J and the rotor's B_m): still accepted in rig files and
        :meth:`aeropend_sim.params.Rig.with_effects`, meaning every effect that names it.
    legacy_default : bool or str
        Its value in a rig file of the pre-family format that omits the switch.
    active_when : callable or None
        ``active_when(values) -> bool``: an extra condition on the parameters for the switched-on
        effect to act (the lag needs T_a > 0).
    negligible : callable or None
        ``negligible(values, sample_period) -> str or None``: for an effect a rig file parameterises
        without naming its switch, the reason it is too fast to show at the rig's sample period
        (the loader then leaves it at its off switch and says so; an explicit switch is obeyed).
    """

    modes: tuple[str, str] | None = None
    legacy_switch: str | None = None
    legacy_default: bool | str = False
    active_when: Callable[[Mapping[str, float]], bool] | None = field(default=None, compare=False)
    negligible: Callable[[Mapping[str, float], float], str | None] | None = field(default=None, compare=False)

    @property
    def switch(self) -> str:
        """Its name in the ``effects:`` section."""
        return self.name

    @property
    def off(self) -> bool | str:
        """Switch value that turns it off."""
        return self.modes[1] if self.modes else False

    @property
    def on(self) -> bool | str:
        """Switch value that turns it on."""
        return self.modes[0] if self.modes else True

    def is_on(self, value: bool | str) -> bool:
        """Whether a switch value turns it on."""
        return value == self.on
