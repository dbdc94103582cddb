"""Candidate-function libraries for sparse identification (thesis §3.2.1, §5.2.1).

A :class:`CandidateLibrary` is an ordered list of *named* candidate functions of named
variables (states and inputs, SI units), evaluated column by column into the library matrix
Θ (N, M). Named columns make the identified equations physically readable (``sin(θ)``,
``ω₁²``) and let one library serve the strong form (Θ evaluated at the samples) and the weak
form (Θ's columns integrated against test functions by pysindy's ``WeakPDELibrary``).

Builders:

* :func:`thesis_library` — the thesis' library Θ(θ, θ̇, i_a, ω₁, v_a): a constant, the
  variables, all their products of degree 2 and sin/cos of every variable (31 columns for the
  five variables, the rows of thesis Figs. 5.3/5.4);
* :func:`physics_library` — only named physical candidates (θ̇, sin θ, ω₁², i_a, ω₁, v_a and
  optionally ω₁|ω₁|, sign(θ̇), ...);
* :func:`collinearity_report` — condition number of the column-normalised library and the most
  correlated column pairs (e.g. θ vs sin θ at small angles, i_a vs sin i_a).
"""

from __future__ import annotations

import itertools
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from aeropend_ident.errors import LibraryError

#: Readable symbols of the aeropendulum variables (names as in ``Trajectory.channels()``).
SYMBOLS: dict[str, str] = {
    "theta": "θ",
    "theta_dot": "θ̇",
    "i_a": "i_a",
    "omega_rotor": "ω₁",
    "omega_prop": "ω₂",
    "v_a": "v_a",
    "duty": "τ",
}

Data = Mapping[str, np.ndarray]
Func = Callable[[Data], np.ndarray]


def symbol(name: str) -> str:
    """Readable symbol of a variable (its name if it has none)."""
    return SYMBOLS.get(name, name)


@dataclass(frozen=True)
class Candidate:
    """One library column.

    Attributes
    ----------
    name : str
        Readable name (``"sin(θ)"``, ``"ω₁²"``), unique in a library.
    variables : tuple of str
        Variables the function reads.
    func : callable
        ``func(data) -> ndarray (N,)`` with ``data`` mapping variable names to arrays (N,).
    regressor : callable, optional
        The same function estimated from *noisy samples* without the bias the noise puts on
        ``func`` (errors in variables), used when a regression column is built from measured
        data (``CandidateLibrary.evaluate(data, regressor=True)``); ``func`` is kept for
        simulation. E.g. ω₁² from ω₁,k·(ω₁,k−1 + ω₁,k+1)/2 (:func:`lagged_square`). None: ``func``.
    """

    name: str
    variables: tuple[str, ...]
    func: Func = field(repr=False)
    regressor: Func | None = field(default=None, repr=False)


@dataclass(frozen=True)
class CandidateLibrary:
    """An ordered set of named candidate functions (the columns of Θ).

    Attributes
    ----------
    candidates : tuple of Candidate
    """

    candidates: tuple[Candidate, ...]

    def __post_init__(self) -> None:
        names = [c.name for c in self.candidates]
        dup = sorted({n for n in names if names.count(n) > 1})
        if dup:
            raise LibraryError(f"duplicate candidate name(s) {dup}")
        if not names:
            raise LibraryError("a library needs at least one candidate")

    @property
    def names(self) -> list[str]:
        """Column names, in order."""
        return [c.name for c in self.candidates]

    @property
    def variables(self) -> list[str]:
        """Every variable some candidate reads (sorted)."""
        return sorted({v for c in self.candidates for v in c.variables})

    def __len__(self) -> int:
        return len(self.candidates)

    def __add__(self, other: CandidateLibrary) -> CandidateLibrary:
        """Concatenation; a candidate of ``other`` whose name is already present is skipped."""
        have = set(self.names)
        return CandidateLibrary(self.candidates + tuple(c for c in other.candidates if c.name not in have))

    def without(self, *names: str) -> CandidateLibrary:
        """Copy without the named candidates (unknown names raise)."""
        bad = sorted(set(names) - set(self.names))
        if bad:
            raise LibraryError(f"library has no candidate(s) {bad}")
        return CandidateLibrary(tuple(c for c in self.candidates if c.name not in names))

    def evaluate(self, data: Data, regressor: bool = False) -> np.ndarray:
        """Library matrix Θ, shape (N, M), one column per candidate.

        ``regressor=True`` evaluates each candidate's ``regressor`` where it has one (a column
        built from noisy samples, see :class:`Candidate`), ``func`` otherwise.

        Raises
        ------
        LibraryError
            If a variable is missing (the message names the candidates that need it), arrays
            have different lengths or a column is not finite.
        """
        missing = [v for v in self.variables if v not in data]
        if missing:
            need = [c.name for c in self.candidates if set(c.variables) & set(missing)]
            raise LibraryError(
                f"data lacks variable(s) {missing} needed by candidate(s) {need}; has {sorted(data)}"
            )
        n = {v: np.asarray(data[v]).shape for v in self.variables}
        if len(set(n.values())) > 1:
            raise LibraryError(f"variables have different shapes {n}")
        length = next(iter(n.values()))[0] if n else None
        cols = []
        for c in self.candidates:
            f = c.regressor if (regressor and c.regressor is not None) else c.func
            y = np.asarray(f(data), dtype=float)
            if y.ndim == 0 or y.shape == ():
                y = np.full(length if length is not None else 1, float(y))
            if not np.isfinite(y).all():
                k = int(np.flatnonzero(~np.isfinite(y))[0])
                raise LibraryError(f"candidate {c.name} is not finite at sample {k} ({y[k]!r})")
            cols.append(y)
        return np.column_stack(cols)


def _var(v: str) -> Candidate:
    return Candidate(symbol(v), (v,), lambda d, v=v: np.asarray(d[v], dtype=float))


def _product(a: str, b: str) -> Candidate:
    name = f"{symbol(a)}²" if a == b else f"{symbol(a)}·{symbol(b)}"
    return Candidate(
        name, (a, b), lambda d, a=a, b=b: np.asarray(d[a], dtype=float) * np.asarray(d[b], dtype=float)
    )


def _unary(fname: str, f: Callable[[np.ndarray], np.ndarray], v: str) -> Candidate:
    return Candidate(f"{fname}({symbol(v)})", (v,), lambda d, f=f, v=v: f(np.asarray(d[v], dtype=float)))


def constant() -> Candidate:
    """The constant column ``1``."""
    return Candidate("1", (), lambda d: np.ones(len(next(iter(d.values())))))


def thesis_library(
    variables: Sequence[str] = ("theta", "theta_dot", "i_a", "omega_rotor", "v_a"),
    degree: int = 2,
    trig: bool = True,
    bias: bool = True,
) -> CandidateLibrary:
    """Polynomial (degree ≤ 2) + trigonometric library of thesis §5.2.1 (Figs. 5.3/5.4 rows).

    Parameters
    ----------
    variables : sequence of str
        Variable names (states then inputs), e.g. ``("theta", "theta_dot", "i_a",
        "omega_rotor", "v_a")``.
    degree : {1, 2}
        Highest polynomial degree (products of pairs, squares included, for 2).
    trig : bool
        Add sin(x) and cos(x) of every variable.
    bias : bool
        Add the constant column.

    Returns
    -------
    CandidateLibrary
        ``1``, x_i, x_i·x_j (i ≤ j), sin(x_i), cos(x_i): 31 columns for five variables.
    """
    if degree not in (1, 2):
        raise LibraryError(f"degree = {degree!r}; the thesis library has degree 1 or 2")
    cands: list[Candidate] = [constant()] if bias else []
    cands += [_var(v) for v in variables]
    if degree == 2:
        cands += [_product(a, b) for a, b in itertools.combinations_with_replacement(variables, 2)]
    if trig:
        for v in variables:
            cands += [_unary("sin", np.sin, v), _unary("cos", np.cos, v)]
    return CandidateLibrary(tuple(cands))


def physics_library(
    variables: Sequence[str] = ("theta", "theta_dot", "i_a", "omega_rotor", "v_a"),
    extras: Sequence[str] = (),
    friction_velocity: float = 0.01,
) -> CandidateLibrary:
    """Named physical candidates of the aeropendulum model (thesis Eqs. 3.1-3.10).

    Always (for the variables present): θ̇, sin θ, ω₁², i_a, ω₁, v_a. ``extras`` may add
    ``"omega_abs"`` (ω₁|ω₁|, propeller drag / signed thrust), ``"sign_theta_dot"``
    (tanh(θ̇/v_ε), Coulomb friction), ``"theta"`` (θ, to expose θ vs sin θ), ``"cos_theta"``,
    ``"sign_omega"`` (tanh(ω₁/1 rad/s)) and ``"bias"`` (constant).

    Raises
    ------
    LibraryError
        On an unknown extra.
    """
    vs = set(variables)
    cands: list[Candidate] = []
    if "theta_dot" in vs:
        cands.append(_var("theta_dot"))
    if "theta" in vs:
        cands.append(_unary("sin", np.sin, "theta"))
    if "omega_rotor" in vs:
        cands.append(_product("omega_rotor", "omega_rotor"))
    for v in ("i_a", "omega_rotor", "v_a", "duty"):
        if v in vs:
            cands.append(_var(v))
    known = {
        "omega_abs": lambda: Candidate("ω₁|ω₁|", ("omega_rotor",),
                                       lambda d: d["omega_rotor"] * np.abs(d["omega_rotor"])),
        "sign_theta_dot": lambda: Candidate("sgn(θ̇)", ("theta_dot",),
                                            lambda d: np.tanh(d["theta_dot"] / friction_velocity)),
        "theta": lambda: _var("theta"),
        "cos_theta": lambda: _unary("cos", np.cos, "theta"),
        "sign_omega": lambda: Candidate("sgn(ω₁)", ("omega_rotor",), lambda d: np.tanh(d["omega_rotor"])),
        "bias": constant,
    }
    bad = sorted(set(extras) - set(known))
    if bad:
        raise LibraryError(f"unknown extra candidate(s) {bad}; expected some of {sorted(known)}")
    cands += [known[e]() for e in extras]
    return CandidateLibrary(tuple(cands))


@dataclass(frozen=True)
class CollinearityReport:
    """How well a library's columns can be told apart on some data.

    Attributes
    ----------
    condition_number : float
        2-norm condition number of Θ with every column scaled to unit RMS (∞ if rank deficient).
    rank : int
        Numerical rank of the scaled Θ.
    n_columns : int
    pairs : list of (str, str, float)
        Column pairs with |correlation| ≥ the report threshold, most correlated first
        (correlation of the columns about zero, i.e. cosine similarity, so that a constant
        column is compared too).
    """

    condition_number: float
    rank: int
    n_columns: int
    pairs: list[tuple[str, str, float]]

    def summary(self, max_pairs: int = 10) -> str:
        """Readable multi-line summary."""
        lines = [f"condition number {self.condition_number:.3g}, rank {self.rank}/{self.n_columns}"]
        lines += [f"  {a} ~ {b}: {r:+.5f}" for a, b, r in self.pairs[:max_pairs]]
        return "\n".join(lines)


def collinearity_report(
    theta: np.ndarray, names: Sequence[str], threshold: float = 0.99
) -> CollinearityReport:
    """Condition number and near-collinear column pairs of a library matrix.

    Parameters
    ----------
    theta : ndarray, shape (N, M)
        Library matrix (strong or weak form).
    names : sequence of str, length M
        Column names.
    threshold : float
        Report pairs whose |cosine similarity| is at least this.
    """
    th = np.asarray(theta, dtype=float)
    if th.ndim != 2 or th.shape[1] != len(names):
        raise LibraryError(f"theta has shape {th.shape}; expected (N, {len(names)})")
    rms = np.sqrt(np.mean(th**2, axis=0))
    scaled = th / np.where(rms > 0, rms, 1.0)
    s = np.linalg.svd(scaled, compute_uv=False)
    tol = s.max() * max(th.shape) * np.finfo(float).eps
    rank = int((s > tol).sum())
    cond = float(s.max() / s.min()) if s.min() > tol else float("inf")
    unit = scaled / np.where(np.linalg.norm(scaled, axis=0) > 0, np.linalg.norm(scaled, axis=0), 1.0)
    corr = unit.T @ unit
    pairs = [
        (names[i], names[j], float(corr[i, j]))
        for i, j in itertools.combinations(range(len(names)), 2)
        if abs(corr[i, j]) >= threshold
    ]
    pairs.sort(key=lambda p: -abs(p[2]))
    return CollinearityReport(condition_number=cond, rank=rank, n_columns=len(names), pairs=pairs)


def structured_library(
    variables: Sequence[str] = ("theta", "theta_dot", "i_a", "omega_rotor", "v_a"),
) -> dict[str, CandidateLibrary]:
    """One physically plausible library per equation (model effects of ``docs/model.md``).

    Each equation is offered the terms of every effect the plant model can switch on for it, not
    only the true ones:

    * dθ/dt (target ``theta``, the kinematic equation): 1, θ, θ̇, sin θ;
    * θ̈ (target ``theta_dot``): 1, θ, θ̇, sin θ, cos θ, sgn θ̇ (Coulomb), ω₁ and ω₁² (thrust
      laws); needs θ, θ̇ and ω₁;
    * di_a/dt (``i_a``): 1, i_a, ω₁ (back-EMF), v_a, ω₁² ;
    * dω₁/dt (``omega_rotor``): i_a, ω₁, ω₁² (propeller drag), sgn ω₁ (Coulomb; no separate
      constant: for a rotor that only turns one way sgn ω₁ ≡ 1 and the two are the same column).

    Only equations whose variables are all present are returned.
    """
    vs = set(variables)
    out: dict[str, CandidateLibrary] = {}
    if {"theta", "theta_dot"} <= vs:
        out["theta"] = CandidateLibrary(
            (constant(), _var("theta"), _var("theta_dot"), _unary("sin", np.sin, "theta"))
        )
    if {"theta", "theta_dot", "omega_rotor"} <= vs:
        out["theta_dot"] = CandidateLibrary((
            constant(), _var("theta"), _var("theta_dot"), _unary("sin", np.sin, "theta"),
            _unary("cos", np.cos, "theta"),
            Candidate("sgn(θ̇)", ("theta_dot",), lambda d: np.tanh(np.asarray(d["theta_dot"]) / 0.01)),
            _var("omega_rotor"), _product("omega_rotor", "omega_rotor"),
        ))
    if {"i_a", "omega_rotor", "v_a"} <= vs:
        out["i_a"] = CandidateLibrary((
            constant(), _var("i_a"), _var("omega_rotor"), _var("v_a"), _product("omega_rotor", "omega_rotor"),
        ))
    if {"i_a", "omega_rotor"} <= vs:
        out["omega_rotor"] = CandidateLibrary((
            _var("i_a"), _var("omega_rotor"), _product("omega_rotor", "omega_rotor"),
            Candidate("sgn(ω₁)", ("omega_rotor",), lambda d: np.tanh(np.asarray(d["omega_rotor"]))),
        ))
    return out


def lagged_square(v: str) -> Candidate:
    """x² of a measured variable, with the errors-in-variables-free regressor x_k·(x_k−1 + x_k+1)/2.

    With white measurement noise e (variance σ²), the square of a sample is biased,
    E[(x + e)²] = x² + σ², which moves the coefficient of a thrust term K_q·ω₁² by the share σ²
    takes of the mean ω₁² (about 1 % at 20 dB on a ``density_prbs`` record). The product of a
    sample with its neighbours' mean has independent noise factors, so its expectation is
    x_k·(x_k−1 + x_k+1)/2 = x_k² + O(dt²·x·ẍ), without σ². The end samples use their one neighbour.
    """
    def lagged(d: Data, v: str = v) -> np.ndarray:
        x = np.asarray(d[v], dtype=float)
        if x.size < 3:
            return x * x
        nb = np.empty_like(x)
        nb[1:-1] = 0.5 * (x[:-2] + x[2:])
        nb[0], nb[-1] = x[1], x[-2]
        return x * nb

    return Candidate(f"{symbol(v)}²", (v,), lambda d, v=v: np.asarray(d[v], dtype=float) ** 2,
                     regressor=lagged)


#: Regularisation speed [rad/s] of sgn θ̇ in the friction candidate (as :func:`physics_library`).
FRICTION_VELOCITY = 0.01


def pendulum_library(friction: bool = True, friction_velocity: float = FRICTION_VELOCITY
                     ) -> CandidateLibrary:
    """Candidates of the pendulum equation θ̈ (thesis Eqs. 3.1-3.3): damping θ̇, gravity sin θ,
    thrust ω₁² and, with ``friction``, Coulomb friction sgn θ̇ (tanh(θ̇/v_ε)).

    i_a and v_a are deliberately absent: they reach θ̈ only through the thrust path (v_a → i_a →
    ω₁ → thrust), so as direct terms they can only fit noise or stand in for a biased thrust
    term (on the rig's sensor set at 30 dB they came out as −724 i_a + 26.8 ω₁ + 15.7 v_a).
    ω₁² carries the noise-free regressor of :func:`lagged_square`.
    """
    cands = [_var("theta_dot"), _unary("sin", np.sin, "theta"), lagged_square("omega_rotor")]
    if friction:
        v_eps = friction_velocity
        cands.append(Candidate("sgn(θ̇)", ("theta_dot",),
                               lambda d: np.tanh(np.asarray(d["theta_dot"], dtype=float) / v_eps)))
    return CandidateLibrary(tuple(cands))


def physics_structured_library(
    variables: Sequence[str] = ("theta", "i_a", "omega_rotor", "v_a"), friction: bool = True,
    drag: bool = True,
) -> dict[str, CandidateLibrary]:
    """Which variable may enter which equation, from the rig's physics (thesis Eqs. 3.1-3.8).

    * θ̈ (target ``theta_dot``): :func:`pendulum_library` (θ̇, sin θ, ω₁², sgn θ̇); needs θ, ω₁;
    * di_a/dt (``i_a``): i_a, ω₁ (back-EMF), v_a (thesis Eq. 3.5); needs i_a, ω₁, v_a;
    * dω₁/dt (``omega_rotor``): i_a (torque), ω₁ (viscous), and with ``drag`` ω₁² (propeller
      drag torque, ω₁|ω₁| for a rotor turning one way) (thesis Eq. 3.8); needs i_a, ω₁.

    θ̇ need not be a recorded variable: the pendulum equation is fitted in the second-order weak
    form (:mod:`aeropend_ident.sindy.second_order`), where θ̇ is integrated onto the test functions.
    Only equations whose variables are present are returned.
    """
    vs = set(variables)
    out: dict[str, CandidateLibrary] = {}
    if {"theta", "omega_rotor"} <= vs:
        out["theta_dot"] = pendulum_library(friction=friction)
    if {"i_a", "omega_rotor", "v_a"} <= vs:
        out["i_a"] = CandidateLibrary((_var("i_a"), _var("omega_rotor"), _var("v_a")))
    if {"i_a", "omega_rotor"} <= vs:
        rotor = [_var("i_a"), _var("omega_rotor")]
        if drag:
            rotor.append(_product("omega_rotor", "omega_rotor"))
        out["omega_rotor"] = CandidateLibrary(tuple(rotor))
    return out
