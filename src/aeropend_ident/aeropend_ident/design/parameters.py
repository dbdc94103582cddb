"""D-optimal design for the parameters a fit could not determine.

The Fisher information of the logged outputs about parameters p_j (in log coordinates, so its
inverse gives relative variances) for white measurement noise of σ_c per channel c:

    F = Σ_c S_cᵀ S_c / σ_c²,   S_c[k, j] = ∂y_c[k] / ∂ln p_j,

the sensitivities from forward differences (relative step :data:`REL_STEP`) of the rig's compiled
replays from rest at the logging period (no new integrator). The parameters are the ones to
determine and the **nuisance** parameters fitted beside them (a ``rig fit`` result's FITTED
lines): left out, a parameter confounded with a nuisance one would read better than it is. The
design is Ds-optimal: it maximises −log det of the block of the parameters to determine in
(F_before + F_design + F_prior)⁻¹ (log det of the whole when there is no nuisance parameter:
D-optimal). F_before is the information of the earlier recordings'
commands replayed the same way (from rest, open loop; for closed-loop logs an approximation),
F_prior = I (a relative prior σ of 1 per parameter, one e-fold: a parameter no recording
determines reads ≈ 100 %). Each parameter's predicted relative 1σ is
sqrt(diag((F_before + F_prior)⁻¹)) before and sqrt(diag((F_before + F_design + F_prior)⁻¹)) after.
Like every Cramér-Rao figure it is a lower bound: model error and a closed loop widen it.

No rclpy import: this module runs without ROS.
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from aeropend_ident.design.sequence import (
    ANGLE_PENALTY,
    BUDGET_S,
    AprbsShape,
    DesignError,
    Limits,
    angle_margin,
    angle_penalty,
    aprbs_vector,
    check_mode,
    default_evaluations,
    search,
    sequence,
    spread_cap,
)
from aeropend_ident.greybox.batch import RigReplays, single_blas
from aeropend_ident.greybox.fit import motor_equilibrium
from aeropend_sim.params import Rig

#: Relative forward-difference step of the sensitivities.
REL_STEP = 1e-3


def perturbed(rig: Rig, key: str, factor: float) -> Rig:
    """``rig`` with parameter ``section.name`` multiplied by ``factor``.

    Raises
    ------
    aeropend_sim.params.RigFileError
        On an unknown key or an invalid value.
    """
    section, name = key.split(".", 1)
    return rig.with_params(section, **{name: rig.values()[key] * factor})


def fisher(rig: Rig, keys: Sequence[str], duty: np.ndarray, dt: float, sigma: Mapping[str, float]
           ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Fisher information (p, p) in log coordinates of ``keys`` under ``duty`` from rest, the
    nominal angle (N,) (NaN when the replay failed) and its sensitivity (p, N) to each key's log
    [rad] (zeros without an angle channel or when the replay failed).

    Parameters
    ----------
    rig : Rig
    keys : sequence of str
        Rig keys ``section.name`` (strictly positive values).
    duty : ndarray, shape (N,)
        Commands on the logging grid.
    dt : float
        Logging period [s].
    sigma : mapping
        Noise σ per logged channel.
    """
    base = rig.with_effects(sensor_noise=False, quantisation=False)
    rigs = [base] + [perturbed(base, k, 1.0 + REL_STEP) for k in keys]
    x0 = np.array([[0.0, 0.0, *motor_equilibrium(r, 0.0)] for r in rigs])
    sim, ok = RigReplays(np.asarray(duty, dtype=float), dt).run(rigs, x0, tuple(sigma))
    p, n = len(keys), np.asarray(duty).size
    if not ok.all():
        return np.zeros((p, p)), np.full(n, np.nan), np.zeros((p, n))
    f = np.zeros((p, p))
    sens_theta = np.zeros((p, n))
    for c, s in sigma.items():
        sens = (sim[c][1:] - sim[c][0]) / math.log1p(REL_STEP)  # (p, N)
        f += sens @ sens.T / s**2
        if c == "theta":
            sens_theta = sens
    return f, sim["theta"][0] if "theta" in sim else np.full(n, np.nan), sens_theta


def angle_spread(sens_theta: np.ndarray, cov: np.ndarray) -> np.ndarray:
    """1σ of the predicted angle (N,) [rad] under a covariance ``cov`` (p, p) of the parameters'
    logs, to first order: sqrt(diag(Sᵀ·cov·S)) for the sensitivity ``sens_theta`` S (p, N)."""
    return np.sqrt(np.maximum(np.einsum("it,ij,jt->t", sens_theta, cov, sens_theta), 0.0))


def relative_sd(f: np.ndarray) -> np.ndarray:
    """sqrt(diag((F + I)⁻¹)): relative 1σ per parameter under the unit prior (module doc)."""
    return np.sqrt(np.diag(np.linalg.inv(f + np.eye(f.shape[0]))))


def ds_criterion(f: np.ndarray, n_interest: int) -> float:
    """−log det of the first ``n_interest`` parameters' block of (F + I)⁻¹ (Ds-optimality; with no
    nuisance parameter, log det(F + I))."""
    cov = np.linalg.inv(f + np.eye(f.shape[0]))
    sign, ld = np.linalg.slogdet(cov[:n_interest, :n_interest])
    return float(-ld) if sign > 0 else -ANGLE_PENALTY


@dataclass
class ParameterDesign:
    """A D-optimal design.

    Attributes
    ----------
    duty, baseline : ndarray, shape (N,)
        Designed sequence and the seeded APRBS of the same shape.
    keys : tuple of str
    logdet, baseline_logdet : float
        The design criterion of each (:func:`ds_criterion`).
    sd_before, sd_after, sd_after_baseline : dict
        Predicted relative 1σ per key: earlier recordings only, with the design, with the APRBS.
    evaluations : int
    elapsed_s : float
    stopped_by : str
        What ended the search (:func:`~aeropend_ident.design.sequence.search`).
    theta : ndarray, shape (N,)
        The design's predicted (nominal) angle [rad] (NaN where the replay failed).
    angle_margin : float
        Largest margin [rad] the design's predicted angle kept from the angle limits
        (:func:`~aeropend_ident.design.sequence.angle_margin` of its :func:`angle_spread`).
    angle_spread : float
        Largest 1σ [rad] of the design's predicted angle under what the earlier recordings leave
        uncertain, uncapped.
    angle_margin_held : bool
        The search found a sequence that keeps the angle ± its margin inside the limits (else it
        kept the one that left them least, whatever its information).
    angle_limits_assured : bool
        ``angle_spread`` within :func:`~aeropend_ident.design.sequence.spread_cap`: else the
        predicted angle depends on parameters the earlier recordings do not determine by more than
        the margin kept, and the limits are not assured.
    steps, baseline_steps : list of (float, float), optional
        A closed-loop design's set points (t [s], θ_ref [rad]) and the seeded ones it started from;
        ``duty`` and ``baseline`` are then the loop's predicted commands.
    """

    duty: np.ndarray
    baseline: np.ndarray
    keys: tuple[str, ...]
    logdet: float
    baseline_logdet: float
    sd_before: dict[str, float]
    sd_after: dict[str, float]
    sd_after_baseline: dict[str, float]
    evaluations: int
    elapsed_s: float
    stopped_by: str = "evaluations"
    theta: np.ndarray | None = None
    angle_margin: float = 0.0
    angle_spread: float = 0.0
    angle_margin_held: bool = True
    angle_limits_assured: bool = True
    steps: list[tuple[float, float]] | None = None
    baseline_steps: list[tuple[float, float]] | None = None


@single_blas
def design_parameters(rig: Rig, keys: Sequence[str], sigma: Mapping[str, float], limits: Limits,
                      shape: AprbsShape | None = None, *, earlier: Sequence[tuple[np.ndarray, float]] = (),
                      nuisance: Sequence[str] = (), seed: int = 0, budget_s: float = BUDGET_S,
                      max_evaluations: int | None = None, mode: str = "open_loop",
                      loop: Any = None) -> ParameterDesign:
    """Search the APRBS parametrisation for the D-optimal sequence (module doc).

    Parameters
    ----------
    rig : Rig
        The fitted rig.
    keys : sequence of str
        Parameters to determine (``section.name``).
    sigma : mapping
        Noise σ per logged channel.
    limits : Limits
    shape : AprbsShape, optional
    earlier : sequence of (ndarray, float)
        Earlier recordings' commands and periods (their information is F_before).
    nuisance : sequence of str
        Parameters fitted beside ``keys`` (their information is counted, their uncertainty not
        optimised).
    seed : int
    budget_s : float
        Wall-time safety net [s] (:func:`~aeropend_ident.design.sequence.search`).
    max_evaluations : int, optional
        Most sequences scored (default :func:`~aeropend_ident.design.sequence.default_evaluations`
        of the p + 1 rigs each replays: the design is then reproducible from its seed).
    mode : str
        ``"open_loop"`` (a command sequence) or ``"reference"`` (set points for ``loop``, the lab's
        controller: the sequence is scored on the command the loop gives on ``rig``, replayed as
        ``rig fit`` replays a closed-loop log; the loop's angle, command range and slew are its
        limits, :func:`aeropend_ident.design.reference.loop_penalty`).
    loop : ControllerLoop, optional
        The lab's controller (:func:`aeropend_ident.design.reference.lab_controller`); with
        ``"reference"`` only.

    Returns
    -------
    ParameterDesign

    Raises
    ------
    ValueError
        Without keys; :class:`~aeropend_ident.design.sequence.DesignError` for an unknown mode, or
        ``reference`` without ``loop``.
    """
    check_mode(mode, ("open_loop", "reference"), where="a parameter design")
    if not keys:
        raise ValueError("no parameter to design for")
    if (mode == "reference") != (loop is not None):
        raise DesignError("a reference design needs the lab's controller (loop=), and only it takes one")
    if loop is not None:
        from aeropend_ident.design.reference import reference_shape

        shape = shape or reference_shape(40.0)
    shape = shape or AprbsShape()
    t0 = time.perf_counter()
    keys = tuple(keys)
    n_i = len(keys)
    every = keys + tuple(k for k in nuisance if k not in keys)
    f0 = sum((fisher(rig, every, d, dt, sigma)[0] for d, dt in earlier), np.zeros((len(every), len(every))))
    calls = 0

    # the angle must stay inside the range for the rig as the earlier recordings know it: the
    # nominal prediction ± its 1σ under what they leave uncertain (the unit prior for a parameter
    # they do not determine; capped), and the recorded angle's own noise and quantum (angle_margin),
    # so a design near a limit keeps a margin where the angle depends on the parameters it is to
    # determine (esc_1 of bench_design_parameters: 0.12 rad above the fitted rig's peak on the rig)
    prior = np.linalg.inv(f0 + np.eye(len(every)))

    play = _Player(rig, shape, limits, loop, every, float(sigma.get("theta", 0.0)))

    def score(z: np.ndarray) -> tuple[float, tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]]:
        nonlocal calls
        calls += 1
        duty, loop_run, loop_sens = play(z)
        f, th, s_th = fisher(rig, every, duty, limits.dt, sigma)
        if loop_run is not None:  # closed loop: the loop's run, and its spread, are the angle limit
            th, s_th = loop_run.seen, loop_sens
        spread = angle_spread(s_th, prior)
        margin = angle_margin(spread, limits, sigma.get("theta", 0.0))
        if loop_run is not None:
            from aeropend_ident.design.reference import loop_penalty

            outside = loop_penalty(loop_run, limits, sigma.get("theta", 0.0), margin)
        else:
            outside = angle_penalty(th, limits, margin)
        return (outside if outside < 0.0 else ds_criterion(f0 + f, n_i)), (f, th, spread, duty)

    z0 = aprbs_vector(shape, seed)
    n = shape.samples(limits.dt)
    if max_evaluations is None:
        if loop is None:
            max_evaluations = default_evaluations(len(every) + 1, n, len(sigma))
        else:  # a loop on the rig and on each perturbed rig per sequence
            from aeropend_ident.design.reference import reference_evaluations

            max_evaluations = reference_evaluations(n * (len(every) + 1))
    # the search keeps the command (a closed loop's run) of the best sequence and of its start
    best_z, best_v, (best_f, theta, spread, duty), v0, (f_base, _, _, base), stopped = search(
        score, z0, seed=seed, budget_s=budget_s, max_evaluations=max_evaluations,
        popsize=8 + shape.size // 6, started=t0)

    def sd(f: np.ndarray) -> dict[str, float]:
        return dict(zip(keys, map(float, relative_sd(f0 + f)[:n_i]), strict=True))

    margin = float(np.max(angle_margin(spread, limits, sigma.get("theta", 0.0)), initial=0.0))
    spread_max = float(np.max(spread, initial=0.0))
    return ParameterDesign(duty=duty, baseline=base, keys=keys, logdet=best_v,
                           baseline_logdet=v0, sd_before=sd(np.zeros_like(f0)), sd_after=sd(best_f),
                           sd_after_baseline=sd(f_base), evaluations=calls,
                           elapsed_s=time.perf_counter() - t0, stopped_by=stopped, theta=theta,
                           angle_margin=margin, angle_spread=spread_max,
                           angle_margin_held=bool(best_v > -ANGLE_PENALTY),
                           angle_limits_assured=bool(spread_max <= spread_cap(limits)),
                           steps=play.steps(best_z), baseline_steps=play.steps(z0))


class _Player:
    """Design vector -> (the command the rig gets, the loop's run or None, the sensitivity (p, N) of
    the loop's recorded angle to each key's log [rad] or None): the APRBS itself open loop, or the
    lab's loop on ``rig`` (and on ``rig`` with each key perturbed, as :func:`fisher` perturbs it)
    following the set points: in closed loop the angle depends on the parameters through the loop."""

    def __init__(self, rig: Rig, shape: AprbsShape, limits: Limits, loop: Any, keys: Sequence[str],
                 sigma_theta: float) -> None:
        self.shape, self.limits, self.loop = shape, limits, loop
        if loop is not None:
            from aeropend_ident.design.reference import set_point_range

            self.span = set_point_range(limits, loop.reach, sigma_theta)
            base = dataclasses.replace(rig.with_effects(sensor_noise=False, quantisation=False),
                                       sample_period=limits.dt)
            self.plants = [base] + [perturbed(base, k, 1.0 + REL_STEP) for k in keys]

    def steps(self, z: np.ndarray) -> list[tuple[float, float]] | None:
        if self.loop is None:
            return None
        from aeropend_ident.design.reference import reference_steps

        return reference_steps(z, self.shape, self.limits, self.span)

    def __call__(self, z: np.ndarray) -> tuple[np.ndarray, Any, np.ndarray | None]:
        if self.loop is None:
            return sequence(z, self.shape, self.limits), None, None
        from aeropend_ident.design.reference import closed_loop, loop_command

        n = round(self.shape.duration / self.limits.dt)
        steps = self.steps(z)
        runs = [closed_loop(self.loop, p, steps, n) for p in self.plants]
        sens = np.array([(r.seen - runs[0].seen) / math.log1p(REL_STEP) for r in runs[1:]])
        if not np.all(np.isfinite(sens)):
            sens = np.zeros_like(sens)
        return loop_command(runs[0]), runs[0], sens


def fitted_keys(fitted_text: str) -> list[str]:
    """Keys a ``rig fit`` result fitted (under a ``# rig fit: FITTED`` comment): the nuisance
    parameters of a design for its undetermined ones."""
    return _keys_under(fitted_text, ("rig fit: FITTED",))


def weak_keys(fitted_text: str) -> list[str]:
    """Keys a ``rig fit`` result left undetermined: the parameter lines under a
    ``# rig fit: STILL TO BE FITTED`` or ``AT SEARCH BOUND`` comment
    (:func:`aeropend_ident.greybox.rig_fit_result.fitted_text`).
    """
    return _keys_under(fitted_text, ("STILL TO BE FITTED", "AT SEARCH BOUND"))


def _keys_under(fitted_text: str, marks: Sequence[str]) -> list[str]:
    """Keys whose line follows a ``# rig fit:`` comment holding one of ``marks``."""
    out: list[str] = []
    section = None
    flagged = False
    for line in fitted_text.splitlines():
        if line and not line[0].isspace() and not line.startswith("#"):
            section = line.split(":")[0].strip()
            flagged = False
            continue
        s = line.strip()
        if s.startswith("# rig fit:"):
            flagged |= any(m in s for m in marks)
            continue
        if section and ":" in s and not s.startswith("#"):
            if flagged:
                out.append(f"{section}.{s.split(':')[0].strip()}")
            flagged = False
    return out
