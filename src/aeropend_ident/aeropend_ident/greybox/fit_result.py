"""What a grey-box fit returns: each parameter's estimate with its 1σ standard error
(:class:`ParameterEstimate`) and the fit as a whole (:class:`GreyBoxResult`: estimates, the
fitted rig, residual figures, the optimiser's report).

The fit is :func:`aeropend_ident.greybox.fit.fit_greybox`. No rclpy import.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from aeropend_ident.greybox.uniform import (
    UniformData,
)
from aeropend_sim.params import Rig


@dataclass(frozen=True)
class ParameterEstimate:
    """One fitted parameter.

    Attributes
    ----------
    name, unit : str
    value : float
        Fitted value.
    std_error : float
        1-σ standard error from the Jacobian (inf if not identifiable from these data).
    initial : float
        Starting value.
    lower, upper : float
        Bounds.
    log : bool
        Fitted as a logarithm.
    at_bound : bool
        The value sits on a bound (the bound, not the data, decided it).
    """

    name: str
    unit: str
    value: float
    std_error: float
    initial: float
    lower: float
    upper: float
    log: bool
    at_bound: bool

    @property
    def relative_std_error(self) -> float:
        """std_error / |value| (inf for a zero value)."""
        return self.std_error / abs(self.value) if self.value != 0.0 else math.inf


@dataclass(frozen=True)
class GreyBoxResult:
    """Outcome of :func:`aeropend_ident.greybox.fit.fit_greybox`.

    Attributes
    ----------
    rig : Rig
        The rig with the fitted parameters (end stops moved with a fitted offset).
    theta_offset : float
        Fitted (or fixed) angle offset θ_model − θ_recorded [rad].
    initial_rig : Rig
        The starting rig (with ``initial`` overrides applied).
    initial_theta_offset : float
    parameters : tuple of ParameterEstimate
        In the order requested.
    cost : float
        ½ Σ (θ_sim − θ_rec)² at the optimum [rad²].
    initial_cost : float
        The same at the starting point.
    nfev, njev : int
        Residual evaluations (simulations, excluding those of the finite-difference Jacobians)
        and Jacobian evaluations, summed over the stages.
    success : bool
    status : int
    message : str
        From :func:`scipy.optimize.least_squares`.
    metrics : dict
        :func:`aeropend_ident.greybox.fit.error_metrics` of the fitted free run on the fit data
        (``nrmse``, ``rms_error``,
        ``max_abs_error``, ...).
    data : UniformData
        The data the fit used.
    theta_fit : ndarray, shape (N,)
        Fitted model's free run on ``data`` (recording frame) [rad].
    elapsed : float
        Wall time [s].
    initial_state : (float, float)
        θ(0) [rad, recording frame] and θ̇(0) [rad/s] of the fitted free run (fitted when
        ``fit_initial_state``, else the estimates); of the first recording when several were fitted.
    initial_states : tuple of (float, float)
        The same for every recording fitted (one pair each).
    """

    rig: Rig
    theta_offset: float
    initial_rig: Rig
    initial_theta_offset: float
    parameters: tuple[ParameterEstimate, ...]
    cost: float
    initial_cost: float
    nfev: int
    njev: int
    success: bool
    status: int
    message: str
    metrics: dict[str, float]
    data: UniformData
    theta_fit: np.ndarray
    elapsed: float
    initial_state: tuple[float, float] = (math.nan, math.nan)
    initial_states: tuple[tuple[float, float], ...] = ()

    @property
    def nrmse(self) -> float:
        """NRMSE of the fit on its own (training) data [1]."""
        return float(self.metrics["nrmse"])

    @property
    def iterations(self) -> int:
        """Jacobian evaluations = trust-region iterations of the optimiser."""
        return self.njev

    def value(self, name: str) -> float:
        """Fitted value of a parameter by name.

        Raises
        ------
        KeyError
            If ``name`` was not fitted.
        """
        for p in self.parameters:
            if p.name == name:
                return p.value
        raise KeyError(f"{name!r} was not fitted; fitted: {[p.name for p in self.parameters]}")

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready summary (parameters with units and standard errors, cost, metrics).

        Non-finite standard errors (parameter on a bound, or not determined) become None.
        """
        return {
            "parameters": [
                {k: (v if not isinstance(v, float) or math.isfinite(v) else None)
                 for k, v in dataclasses.asdict(p).items()}
                for p in self.parameters
            ],
            "theta_offset": self.theta_offset,
            "initial_state": {"theta0": self.initial_state[0], "theta_dot0": self.initial_state[1],
                              "units": ["rad", "rad/s"]},
            "initial_states": [{"recording": part.source, "theta0": a, "theta_dot0": b}
                               for part, (a, b) in zip(self.data.parts(), self.initial_states, strict=False)],
            "cost": self.cost,
            "initial_cost": self.initial_cost,
            "nfev": self.nfev,
            "iterations": self.njev,
            "success": self.success,
            "message": self.message,
            "metrics": self.metrics,
            "grid": {"dt": self.data.dt, "n": len(self.data), "resampled": self.data.resampled,
                     "decimate": self.data.decimate},
            "elapsed_s": self.elapsed,
        }
