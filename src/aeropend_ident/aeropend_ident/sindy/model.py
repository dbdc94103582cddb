"""What SINDy identifies and runs: the data, the identified model and its free run.

:class:`IdentData` (uniformly sampled channels), the targets' names (:func:`lhs`),
:class:`SindyModel` (the sparse coefficients, with its right-hand side), :func:`free_run` of a
model over recorded inputs, :func:`input_instruments` (the noise-free stand-in of a measured
v_a) and the model file (:func:`model_to_dict`, :func:`save_model`). The regressions that
produce a model are in :mod:`aeropend_ident.sindy.core`; the output-error refinement
(:mod:`aeropend_ident.sindy.output_error`) works on this module only, so neither imports the
other in a cycle.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from aeropend_ident.errors import IdentificationError
from aeropend_ident.sindy.libraries import CandidateLibrary, symbol
from aeropend_sim.compiled.plant import derivatives as model_rhs_at
from aeropend_sim.model import TAU_F, plant_model
from aeropend_sim.params import Rig

#: Target state -> readable left-hand side.
TARGET_LHS: dict[str, str] = {
    "theta": "dθ/dt",
    "theta_dot": "θ̈",
    "i_a": "di_a/dt",
    "omega_rotor": "dω₁/dt",
}


#: Target state -> (unit of the derivative, what the equation is called in messages).
TARGET_INFO: dict[str, tuple[str, str]] = {
    "theta": ("rad/s", "kinematic equation dθ/dt"),
    "theta_dot": ("rad/s^2", "pendulum equation θ̈"),
    "i_a": ("A/s", "armature-current equation di_a/dt"),
    "omega_rotor": ("rad/s^2", "rotor-speed equation dω₁/dt"),
}


#: Inputs held constant over each sample period (zero-order hold) by default.
ZOH_INPUTS = ("v_a", "duty")


#: The model's states that have an equation here (names of the rig's state layout,
#: :mod:`aeropend_sim.components.states`; τ_f is the duty cycle without actuator lag).
_MODEL_STATES = ("theta", "theta_dot", "i_a", "omega_rotor")


class NoEquationError(IdentificationError):
    """Every equation was left out (:func:`regression_problem` with ``drop_unidentifiable``).

    Attributes
    ----------
    dropped : dict target -> str
        Why each equation was left out.
    """

    def __init__(self, message: str, dropped: Mapping[str, str]) -> None:
        super().__init__(message)
        self.dropped = dict(dropped)


def lhs(target: str) -> str:
    """Readable left-hand side of a target's equation (``θ̈``, ``di_a/dt``, ``dx/dt``)."""
    return TARGET_LHS.get(target, f"d{symbol(target)}/dt")


# ---------------------------------------------------------------------------------- data
@dataclass
class IdentData:
    """Uniformly sampled data for identification.

    Attributes
    ----------
    t : ndarray, shape (N,)
        Sample times [s], uniform.
    variables : dict[str, ndarray]
        States and inputs, each (N,), SI units (names as in ``Trajectory.channels()``:
        ``theta`` [rad], ``theta_dot`` [rad/s], ``i_a`` [A], ``omega_rotor`` [rad/s], ``v_a``
        [V], ``duty`` [1]).
    derivatives : dict[str, ndarray]
        Time derivatives of states, (N,), for the strong form (exact or estimated).
    source : str
        Provenance.
    """

    t: np.ndarray
    variables: dict[str, np.ndarray]
    derivatives: dict[str, np.ndarray] = field(default_factory=dict)
    source: str = ""

    def __post_init__(self) -> None:
        self.t = np.asarray(self.t, dtype=float)
        n = self.t.size
        if self.t.ndim != 1 or n < 3:
            raise IdentificationError(f"{self.source}: need >= 3 samples, got t of shape {self.t.shape}")
        dt = np.diff(self.t)
        if not (dt > 0).all():
            raise IdentificationError(f"{self.source}: time is not strictly increasing")
        if np.ptp(dt) > 1e-6 * dt.mean():
            raise IdentificationError(
                f"{self.source}: sampling is not uniform (dt from {dt.min():.6g} to {dt.max():.6g} s); "
                "resample first"
            )
        for kind, d in (("variable", self.variables), ("derivative", self.derivatives)):
            for k, v in list(d.items()):
                a = np.asarray(v, dtype=float)
                if a.shape != (n,):
                    raise IdentificationError(
                        f"{self.source}: {kind} {k} has shape {a.shape}, expected ({n},)"
                    )
                bad = ~np.isfinite(a)
                if bad.any():
                    raise IdentificationError(
                        f"{self.source}: {kind} {k} has {int(bad.sum())} non-finite value(s), "
                        f"first at sample {int(np.flatnonzero(bad)[0])}"
                    )
                d[k] = a

    def __len__(self) -> int:
        return int(self.t.size)

    def slice(self, start: int, stop: int) -> IdentData:
        """Samples [start, stop) (time kept, not re-based)."""
        return IdentData(
            t=self.t[start:stop].copy(),
            variables={k: v[start:stop].copy() for k, v in self.variables.items()},
            derivatives={k: v[start:stop].copy() for k, v in self.derivatives.items()},
            source=f"{self.source}[{start}:{stop}]",
        )

    def split(self, train_fraction: float = 0.75) -> tuple[IdentData, IdentData]:
        """Time-ordered split (thesis §5.2.1: 75 % training, 25 % test)."""
        if not 0.0 < train_fraction < 1.0:
            raise IdentificationError(f"train_fraction = {train_fraction!r} must be in (0, 1)")
        k = round(train_fraction * len(self))
        return self.slice(0, k), self.slice(k, len(self))


def data_from_trajectory(traj: Any, rig: Rig | None = None, measured: bool = False,
                         exact_derivatives: bool = False, source: str = "simulation") -> IdentData:
    """Identification data from a :class:`aeropend_sim.simulation.Trajectory`.

    Parameters
    ----------
    traj : Trajectory
    rig : Rig, optional
        Needed for ``exact_derivatives`` (the model's right-hand side at each sample).
    measured : bool
        Use the measured channels (noise/quantisation as configured) instead of the true ones.
    exact_derivatives : bool
        Attach the model's exact derivatives dx/dt = f(x_k, τ_k) of θ, θ̇, i_a, ω₁ (the thesis'
        noise-free case, §5.2.1, where dX/dt "was composed directly from the simulation").
    """
    ch = traj.channels() if measured else traj.true
    names = ("theta", "theta_dot", "i_a", "omega_rotor", "v_a")
    variables = {k: np.asarray(ch[k], dtype=float).copy() for k in names}
    variables["duty"] = np.asarray(traj.duty, dtype=float).copy()
    derivatives: dict[str, np.ndarray] = {}
    if exact_derivatives:
        if rig is None:
            raise IdentificationError("exact_derivatives needs the rig that produced the trajectory")
        model = plant_model(rig)
        u = traj.x[:, TAU_F] if not model.lag else traj.duty
        f = model_rhs_at(model, traj.x, u)[0]  # model.rhs at each sample, bit for bit, compiled
        derivatives = {k: f[:, model.states.index(k)].copy() for k in _MODEL_STATES}
    return IdentData(t=np.asarray(traj.t, dtype=float).copy(), variables=variables,
                     derivatives=derivatives, source=source)


def model_derivatives(rig: Rig, data: IdentData, targets: Sequence[str]) -> dict[str, np.ndarray]:
    """Right-hand side of a rig's model at the data's samples (the f_model of discrepancy SINDy).

    Needs θ, θ̇, ω₁, the duty cycle and, for a dynamic armature, i_a.

    Raises
    ------
    IdentificationError
        If a needed variable is missing or the rig has an actuator lag/delay (its hidden state
        cannot be reconstructed from the data).
    """
    model = plant_model(rig)
    st = model.states
    if model.lag or model.delay > 0 or st.extra:
        hidden = ", ".join(["actuator lag / input delay"] * (model.lag or model.delay > 0)
                           + [f"{s.name} ({s.description})" for s in st.extra])
        raise IdentificationError(
            f"rig {rig.name}: {hidden} switched on; the discrepancy model needs a model whose state is "
            "in the data"
        )
    need = ["theta", "theta_dot", "omega_rotor", "duty"] + (["i_a"] if model.dynamic_current else [])
    missing = [v for v in need if v not in data.variables]
    if missing:
        raise IdentificationError(
            f"{data.source}: the approximate model of rig {rig.name} needs {missing}; data has "
            f"{sorted(data.variables)}"
        )
    v = data.variables
    x = np.zeros((len(data), st.size))
    for name in ("theta", "theta_dot", "omega_rotor") + (("i_a",) if model.dynamic_current else ()):
        x[:, st.index(name)] = v[name]
    x[:, TAU_F] = v["duty"]
    f = model_rhs_at(model, x, v["duty"])[0]  # model.rhs at each sample, bit for bit, compiled
    return {k: f[:, st.index(k)] for k in targets}


def input_step_mask(data: IdentData, width: int) -> np.ndarray:
    """Boolean (N,): False within ± ``width`` samples of a change of the duty cycle.

    Raises
    ------
    IdentificationError
        If the data has no ``duty`` variable.
    """
    if "duty" not in data.variables:
        raise IdentificationError(f"{data.source}: exclude_input_steps needs the duty cycle in the data")
    steps = np.flatnonzero(np.diff(data.variables["duty"]) != 0.0) + 1
    keep = np.ones(len(data), dtype=bool)
    for k in range(-width, width + 1):
        keep[np.clip(steps + k, 0, len(data) - 1)] = False
    return keep


def _advance_states(data: IdentData, held: Sequence[str]) -> IdentData:
    """Every variable advanced one sample except the held inputs (last sample repeated)."""
    return IdentData(
        t=data.t,
        variables={k: (v if k in held else np.r_[v[1:], v[-1]]) for k, v in data.variables.items()},
        source=f"{data.source}(x_k+1, u_k)",
    )


#: A discrepancy base model given as a function: data -> {target: derivative (N,)}.
BaseModel = Callable[[IdentData], Mapping[str, np.ndarray]]


def _base_name(base: Rig | BaseModel) -> str:
    return base.name if isinstance(base, Rig) else getattr(base, "__name__", "model")


def base_derivatives(base: Rig | BaseModel, data: IdentData, targets: Sequence[str]) -> dict[str, np.ndarray]:
    """f_model of discrepancy SINDy: a rig's model (:func:`model_derivatives`) or a function."""
    if isinstance(base, Rig):
        return model_derivatives(base, data, targets)
    out = base(data)
    missing = [tg for tg in targets if tg not in out]
    if missing:
        raise IdentificationError(f"base model {_base_name(base)} gives no derivative for {missing}")
    return {tg: np.asarray(out[tg], dtype=float) for tg in targets}


def check_targets(data: IdentData, targets: Sequence[str], library: CandidateLibrary,
                  need_derivatives: bool) -> None:
    """Refuse what the data cannot support, naming the equation and the missing channel.

    Raises
    ------
    IdentificationError
        Unknown target; the target's state not in the data (e.g. the current equation without
        i_a); a library variable missing; a strong-form derivative missing.
    """
    if not targets:
        raise IdentificationError("no target equation requested")
    for tg in targets:
        if tg not in TARGET_LHS and tg not in data.variables:
            raise IdentificationError(
                f"unknown target {tg!r}; expected some of {list(TARGET_LHS)} or a variable of the data "
                f"{sorted(data.variables)}"
            )
        if tg not in data.variables:
            raise IdentificationError(
                f"{data.source}: the {TARGET_INFO[tg][1]} needs the state {tg} ({symbol(tg)}), which the "
                f"data does not have (variables: {sorted(data.variables)}); record it or drop target {tg!r}"
            )
        if need_derivatives and tg not in data.derivatives:
            raise IdentificationError(
                f"{data.source}: strong-form SINDy needs d{tg}/dt; estimate it "
                "(aeropend_ident.sindy.preprocess.add_derivatives) or use method='weak'"
            )
    missing = [v for v in library.variables if v not in data.variables]
    if missing:
        need = [c.name for c in library.candidates if set(c.variables) & set(missing)]
        raise IdentificationError(
            f"{data.source}: library candidate(s) {need} need {missing}, which the data does not have "
            f"(variables: {sorted(data.variables)}); drop them from the library"
        )


# ---------------------------------------------------------------------------------- model
@dataclass
class SindyModel:
    """An identified sparse model Ẋ = f_base(X, U) + Θ(X, U)·Ξᵀ.

    Attributes
    ----------
    method : str
        ``"sindy"``, ``"ensemble"`` or ``"weak"`` (prefixed ``"discrepancy-"`` with a base model).
    targets : list of str
        Target states, one equation each.
    feature_names : list of str
        Library column names (M).
    coef : ndarray, shape (n_targets, M)
        Ξ in SI units (derivative unit / candidate unit).
    threshold : float
        λ (dimensionless, on the unit-RMS scale).
    coef_std : ndarray, shape (n_targets, M) or None
        Ensemble spread (standard deviation over the bagged models) or output-error standard
        errors; NaN where not estimated (shown as no ± and left out of the model file).
    inclusion : ndarray, shape (n_targets, M) or None
        Ensemble inclusion probability of each term.
    condition_number : float
        Condition number of the normalised regression matrix.
    fit_time : float
        Wall time of the fit [s].
    base : Rig or None
        Approximate model of discrepancy SINDy.
    """

    method: str
    targets: list[str]
    feature_names: list[str]
    coef: np.ndarray
    threshold: float
    library: CandidateLibrary = field(repr=False)
    coef_std: np.ndarray | None = None
    inclusion: np.ndarray | None = None
    condition_number: float = float("nan")
    fit_time: float = 0.0
    base: Rig | BaseModel | None = field(default=None, repr=False)

    def support(self) -> np.ndarray:
        """Boolean (n_targets, M): which terms are active."""
        return self.coef != 0.0

    def coefficient(self, target: str, name: str) -> float:
        """Coefficient of candidate ``name`` in the equation of ``target``."""
        return float(self.coef[self.targets.index(target), self.feature_names.index(name)])

    def terms(self, target: str) -> dict[str, float]:
        """Active terms of one equation: candidate name -> coefficient."""
        row = self.coef[self.targets.index(target)]
        return {n: float(c) for n, c in zip(self.feature_names, row, strict=True) if c != 0.0}

    def predict(self, data: IdentData) -> dict[str, np.ndarray]:
        """Predicted derivatives of every target at the data's samples (strong form)."""
        theta = self.library.evaluate(data.variables)
        out = {tg: theta @ self.coef[i] for i, tg in enumerate(self.targets)}
        if self.base is not None:
            fb = base_derivatives(self.base, data, self.targets)
            out = {tg: out[tg] + fb[tg] for tg in self.targets}
        return out

    def test_mse(self, data: IdentData, exclude_input_steps: int = 0) -> dict[str, float]:
        """Mean squared derivative error per target on data with derivatives (thesis §5.2.2).

        ``exclude_input_steps`` leaves out the samples next to duty steps as in :func:`fit`.
        """
        missing = [tg for tg in self.targets if tg not in data.derivatives]
        if missing:
            raise IdentificationError(f"{data.source}: no derivative(s) {missing} to score against")
        pred = self.predict(data)
        keep = input_step_mask(data, exclude_input_steps) if exclude_input_steps > 0 else slice(None)
        return {tg: float(np.mean((pred[tg] - data.derivatives[tg])[keep] ** 2)) for tg in self.targets}

    def equations(self, precision: int = 4) -> list[str]:
        """Readable equations, e.g. ``θ̈ = −13.82 θ̇ − 131.75 sin(θ) + 1.7285 ω₁²``.

        Ensemble models show ``±σ`` and ``[p]`` (inclusion probability) per term; discrepancy
        models show ``f_model + ...``.
        """
        lines = []
        for i, tg in enumerate(self.targets):
            parts = []
            for j, name in enumerate(self.feature_names):
                c = self.coef[i, j]
                if c == 0.0:
                    continue
                s = f"{abs(c):.{precision}g}"
                if self.coef_std is not None and math.isfinite(self.coef_std[i, j]):
                    s += f"±{self.coef_std[i, j]:.2g}"
                if self.inclusion is not None:
                    s += f"[p={self.inclusion[i, j]:.2f}]"
                term = s if name == "1" else f"{s} {name}"
                parts.append(("− " if c < 0 else "+ ") + term)
            rhs = " ".join(parts) if parts else "0"
            if rhs.startswith("+ "):
                rhs = rhs[2:]
            if self.base is not None:
                rhs = f"f_{_base_name(self.base)} {'' if rhs.startswith('−') else '+ '}{rhs}"
            lines.append(f"{lhs(tg)} = {rhs}")
        return lines

    def derived_parameters(self, gear_ratio: float | None = None, L_over_J: float | None = None
                           ) -> dict[str, tuple[float, str]]:
        """Physical parameters implied by the coefficients (thesis §5.2.1), with units.

        θ̈ = −(c/J)·θ̇ − (mgd/J)·sin θ + (L/J)·K_q·(ω₁/n)² gives c/J, mgd/J and, with the gear
        ratio n = ω₁/ω₂ and L/J, K_q = ξ(ω₁²)·n²/(L/J) (the thesis' K_q = 1.729/((L/J)(N₁/N₂)²));
        L_a·di_a/dt = v_a − R_a·i_a − K_ω·ω₁ gives L_a = 1/ξ(v_a), R_a/L_a = −ξ(i_a),
        K_ω = −ξ(ω₁)·L_a; J_m·dω₁/dt = K_t·i_a − B_m·ω₁ gives K_t/J_m and B_m/J_m. Only
        parameters whose coefficients are in the library and non-zero are returned. For a
        discrepancy model the coefficients are corrections, so nothing is derived.
        """
        if self.base is not None:
            return {}
        out: dict[str, tuple[float, str]] = {}

        def c(tg: str, name: str) -> float | None:
            if tg not in self.targets or name not in self.feature_names:
                return None
            v = self.coefficient(tg, name)
            return v if v != 0.0 else None

        if (v := c("theta_dot", "θ̇")) is not None:
            out["c_over_J"] = (-v, "1/s")
        if (v := c("theta_dot", "sin(θ)")) is not None:
            out["mgd_over_J"] = (-v, "1/s^2")
        if (v := c("theta_dot", "ω₁²")) is not None:
            out["thrust_gain"] = (v, "1/rad")  # (L/J)·K_q/n²: rad/s² per (rad/s)²
            if gear_ratio is not None and L_over_J is not None:
                out["K_q"] = (v * gear_ratio**2 / L_over_J, "N*s^2/rad^2")
        if (inv_l := c("i_a", "v_a")) is not None:
            l_a = 1.0 / inv_l
            out["L_a"] = (l_a, "H")
            if (v := c("i_a", "i_a")) is not None:
                out["R_a_over_L_a"] = (-v, "1/s")
                out["R_a"] = (-v * l_a, "ohm")
            if (v := c("i_a", "ω₁")) is not None:
                out["K_omega"] = (-v * l_a, "V*s/rad")
        if (v := c("omega_rotor", "i_a")) is not None:
            out["K_t_over_J_m"] = (v, "1/(A*s^2)")
        if (v := c("omega_rotor", "ω₁")) is not None:
            out["B_m_over_J_m"] = (-v, "1/s")
        return out


def input_instruments(data: IdentData) -> dict[str, np.ndarray]:
    """Noise-free stand-in for a measured input that is a static function of the duty cycle.

    v_a is the H-bridge's static response to τ (thesis Eq. 4.3), measured with noise. A
    degree-5 polynomial in τ fitted to all samples (the map is a smooth square root) averages
    the noise over the whole record, so the fitted v_a(τ) is practically noise-free and
    serves as its instrument. (A per-level mean would keep the noise of short holds, which
    the regressor of the same subdomain shares.)
    """
    v = data.variables
    if "duty" not in v or "v_a" not in v:
        return {}
    levels = np.unique(v["duty"])
    if levels.size < 2 or levels.size > len(data) // 4:  # not a held command
        return {}
    poly = np.polynomial.Polynomial.fit(v["duty"], v["v_a"], deg=min(5, levels.size - 1))
    return {"v_a": poly(v["duty"])}


def structure_errors(model: SindyModel, truth: Mapping[str, Mapping[str, float]]) -> dict[str, Any]:
    """Compare with a known model: false positives/negatives and coefficient errors per target.

    Parameters
    ----------
    truth : mapping target -> {candidate name: coefficient}

    Returns
    -------
    dict
        Per target: ``false_positive`` (list of names), ``false_negative`` (list), ``max_rel_error``
        (over the true terms; a missed term counts as 1.0).
    """
    out: dict[str, Any] = {}
    for tg, terms in truth.items():
        found = model.terms(tg)
        rel = [abs(found.get(n, 0.0) - c) / abs(c) for n, c in terms.items()]
        out[tg] = {
            "false_positive": sorted(set(found) - set(terms)),
            "false_negative": sorted(set(terms) - set(found)),
            "max_rel_error": float(max(rel)) if rel else 0.0,
        }
    return out


# ---------------------------------------------------------------------------------- free run
@dataclass(frozen=True)
class FreeRun:
    """Free-run simulation of an identified model against data.

    Attributes
    ----------
    t : ndarray, shape (N,)
    states : dict[str, ndarray]
        Simulated states (targets, plus θ integrated from θ̇ when θ̈ is modelled).
    nrmse : dict[str, float]
        RMS(simulated − measured)/std(measured) per simulated state (inf if it diverged).
    """

    t: np.ndarray
    states: dict[str, np.ndarray]
    nrmse: dict[str, float]


def free_run(model: SindyModel, data: IdentData, substeps: int = 2) -> FreeRun:
    """Simulate the identified model from the data's first sample, inputs held from the data.

    The simulated states are the model's targets (θ integrated from θ̇ when ``theta_dot`` is a
    target and ``theta`` is not); every other library variable (v_a, and measured states the
    model does not describe) is taken from the data, held over each sample period (zero-order
    hold, like the duty cycle). Fixed-step RK4 with ``substeps`` steps per sample.

    Raises
    ------
    IdentificationError
        If a needed variable is not in the data.
    """
    states = list(model.targets)
    if "theta_dot" in states and "theta" not in states:
        states = ["theta", *states]
    need = set(model.library.variables) | set(states)
    if isinstance(model.base, Rig):  # the approximate model reads the whole model state and τ
        need |= {"theta", "theta_dot", "omega_rotor", "duty", "i_a"} & set(data.variables)
    missing = sorted(v for v in need if v not in data.variables)
    if missing:
        raise IdentificationError(
            f"{data.source}: free run needs {missing}; data has {sorted(data.variables)}"
        )
    n = len(data)
    x = np.array([data.variables[s][0] for s in states], dtype=float)
    out = np.full((n, len(states)), np.nan)
    out[0] = x
    idx = {s: i for i, s in enumerate(states)}
    exo_names = sorted(v for v in need if v not in idx)
    exo_data = {v: np.asarray(data.variables[v], dtype=float) for v in exo_names}
    funcs = [c.func for c in model.library.candidates]
    row = np.empty(len(funcs))
    coef_rows = [model.coef[j] for j in range(len(model.targets))]
    idx_items = list(idx.items())
    # where each simulated state's derivative comes from: a target's row of Ξ, or θ̇ for θ
    source = [(i, -1 if (s == "theta" and s not in model.targets) else model.targets.index(s))
              for s, i in idx_items]
    i_theta_dot = idx.get("theta_dot", -1)

    def library_row(vals: dict[str, np.ndarray]) -> np.ndarray:
        # the library row of CandidateLibrary.evaluate without its per-column checks (the hot loop);
        # a non-finite value is re-evaluated there to raise the library's own error
        for j, f in enumerate(funcs):
            y = np.asarray(f(vals), dtype=float)
            row[j] = y if y.ndim == 0 else y[0]
        if not np.isfinite(row).all():
            model.library.evaluate(vals)
        return row

    def rhs(xs: np.ndarray, exo: dict[str, np.ndarray]) -> np.ndarray:
        vals = dict(exo)
        for s, i in idx_items:
            vals[s] = xs[i:i + 1]
        if model.base is None:
            r = library_row(vals)
            deriv = [r @ c for c in coef_rows]
        else:
            d = IdentData(t=np.arange(3.0), variables={k_: np.repeat(v, 3) for k_, v in vals.items()})
            pred = model.predict(d)
            deriv = [pred[tg][0] for tg in model.targets]
        dx = np.empty(len(states))
        for i, j in source:
            dx[i] = xs[i_theta_dot] if j < 0 else deriv[j]
        return dx

    h = float(np.mean(np.diff(data.t))) / substeps
    with np.errstate(all="ignore"):
        for k in range(n - 1):
            exo = {v: a[k:k + 1] for v, a in exo_data.items()}  # inputs held over the sample period
            for _ in range(substeps):
                k1 = rhs(x, exo)
                k2 = rhs(x + 0.5 * h * k1, exo)
                k3 = rhs(x + 0.5 * h * k2, exo)
                k4 = rhs(x + h * k3, exo)
                x = x + h / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)
            if not np.isfinite(x).all() or np.abs(x).max() > 1e9:
                break
            out[k + 1] = x
    sim = {s: out[:, i] for s, i in idx.items()}
    nrmse = {}
    for s, y in sim.items():
        ref = data.variables[s]
        ok = np.isfinite(y).all()
        nrmse[s] = float(np.sqrt(np.mean((y - ref) ** 2)) / (np.std(ref) or 1.0)) if ok else float("inf")
    return FreeRun(t=data.t.copy(), states=sim, nrmse=nrmse)


# ---------------------------------------------------------------------------------- model file
def model_to_dict(
    model: SindyModel, gear_ratio: float | None = None, L_over_J: float | None = None,
    test_mse: Mapping[str, float] | None = None, free_run_nrmse: Mapping[str, float] | None = None,
    provenance: Mapping[str, Any] | None = None,
) -> dict[str, Any]:
    """Plain-data description of an identified model (for a YAML model file).

    Contains the method, λ, the readable equations, every non-zero coefficient per equation
    (with ensemble spread and inclusion probability when available), the derived physical
    parameters with units, the condition number, fit time and optional test scores.
    """
    eqs: dict[str, Any] = {}
    for i, tg in enumerate(model.targets):
        terms = {}
        for j, name in enumerate(model.feature_names):
            c = float(model.coef[i, j])
            if c == 0.0:
                continue
            entry: dict[str, float] = {"coefficient": c}
            if model.coef_std is not None and math.isfinite(model.coef_std[i, j]):
                entry["std"] = float(model.coef_std[i, j])
            if model.inclusion is not None:
                entry["inclusion"] = float(model.inclusion[i, j])
            terms[name] = entry
        eqs[tg] = {"lhs": lhs(tg), "unit": TARGET_INFO.get(tg, ("", ""))[0], "terms": terms}
    out: dict[str, Any] = {
        "method": model.method,
        "threshold": float(model.threshold),
        "library": list(model.feature_names),
        "equations_text": model.equations(),
        "equations": eqs,
        "derived_parameters": {k: {"value": float(v), "unit": u}
                               for k, (v, u) in model.derived_parameters(gear_ratio, L_over_J).items()},
        "condition_number": float(model.condition_number),
        "fit_time_s": float(model.fit_time),
    }
    if model.base is not None:
        out["base_model"] = _base_name(model.base)
    if test_mse is not None:
        out["test_mse"] = {k: float(v) for k, v in test_mse.items()}
    if free_run_nrmse is not None:
        out["free_run_nrmse"] = {k: float(v) for k, v in free_run_nrmse.items()}
    if provenance is not None:
        out["provenance"] = dict(provenance)
    return out


def save_model(path: str | Path, model: SindyModel, **kw: Any) -> None:
    """Write :func:`model_to_dict` as a YAML model file (UTF-8, readable symbols kept)."""
    text = yaml.safe_dump(model_to_dict(model, **kw), sort_keys=False, allow_unicode=True)
    Path(path).write_text(text, encoding="utf-8")
