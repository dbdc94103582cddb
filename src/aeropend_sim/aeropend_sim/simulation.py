"""Sampled simulation of the plant model: batch API and per-sample stepper.

Sampling semantics (the same for the simulated plant node and the hardware):

* sample k is taken at t_k = k·T_s from the state x(t_k);
* the duty cycle τ_k commanded for sample k is held (zero-order hold) over [t_k, t_{k+1});
* with the input delay T_d switched on, the actuator sees τ(t − T_d): the held input is shifted
  in time, with τ = ``tau_before`` before the first command arrives.

Two backends integrate the same equations (the registry's term functions):

* ``"compiled"`` (default): fixed-step classical RK4 compiled by numba
  (:mod:`aeropend_sim.compiled`), sub-steps of at most 0.34 ms (at least 6 per sample), the
  sample split where a fractional input delay switches the command, end-stop contact switches
  located inside the sub-step. Its cost does not depend on how often the input changes (≥ 1000×
  real time on the thesis rig with every effect on, for steps and per-sample inputs alike);
  :func:`simulate_batch` replays one input with many parameter sets, shared out to threads;
* ``"lsoda"``: SciPy's LSODA (``scipy.integrate.odeint``, rtol 1e-8) over each interval on which
  the delayed input is constant; the reference the compiled backend is tested against (agreement
  per effect set in docs/model.md, "Simulation backends").
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from aeropend_sim.compiled.plant import MAX_SUBSTEPS, CompiledPlant, compiled_plant
from aeropend_sim.components.states import N_CHAIN
from aeropend_sim.model import I_A, TAU_F, PlantModel, plant_model
from aeropend_sim.params import Rig

#: ODE tolerances (relative, absolute) of the LSODA backend.
RTOL, ATOL = 1e-8, 1e-10

#: Simulation backends (module doc); the first is the default.
BACKENDS: tuple[str, ...] = ("compiled", "lsoda")
DEFAULT_BACKEND = BACKENDS[0]


def _odeint() -> Any:
    """``scipy.integrate.odeint``, imported on the first LSODA run: scipy.integrate takes about 1 s to
    import, and the processes that never run LSODA (the simulator node on the compiled backend, every
    command that replays) need not pay for it."""
    from scipy.integrate import odeint

    return odeint


class SimulationError(ValueError):
    """Invalid simulation input (NaN or out-of-range duty cycle, bad initial state, ...).

    ``sample``: the sample at which a compiled replay's state turned non-finite (None otherwise).
    """

    sample: int | None = None


def _check_duty(duty: np.ndarray) -> np.ndarray:
    duty = np.asarray(duty, dtype=float)
    if duty.ndim != 1:
        raise SimulationError(f"duty must be a 1-D array of duty cycles, got shape {duty.shape}")
    bad = ~np.isfinite(duty) | (duty < 0.0) | (duty > 1.0)
    if bad.any():
        k = int(np.flatnonzero(bad)[0])
        raise SimulationError(
            f"duty[{k}] = {duty[k]!r} is not a finite fraction in [0, 1] "
            f"({int(bad.sum())} bad sample(s))"
        )
    return duty


def _check_backend(backend: str) -> str:
    if backend not in BACKENDS:
        raise SimulationError(f"backend {backend!r}: expected one of {list(BACKENDS)}")
    return backend


def _check_state(model: PlantModel, x0: Any, rows: int | None = None) -> np.ndarray:
    """The whole initial state (n,) (``rows``: (rows, n), one given row repeated) of ``x0``: None
    (at rest: every state at its initial value), the rig's states, or the chain's five (the
    effects' states then at their initial values, :meth:`StateLayout.complete`)."""
    st = model.states
    x = st.initial() if x0 is None else np.array(x0, dtype=float)
    try:
        x = st.complete(x, "initial state" if rows is None else "initial states").copy()
    except ValueError as exc:
        raise SimulationError(f"{exc}, finite numbers") from None
    if rows is not None:
        x = np.repeat(x[None, :], rows, axis=0) if x.ndim == 1 else x
        if x.shape != (rows, st.size):
            raise SimulationError(f"initial states of shape {np.shape(x0)}: expected ({st.size},) or "
                                  f"({rows}, {st.size}) (or the chain's {N_CHAIN} states per row), finite "
                                  "numbers")
    elif x.ndim != 1:
        raise SimulationError(f"initial state of shape {x.shape}: expected ({st.size},) {list(st.names)}")
    if not np.isfinite(x).all():
        raise SimulationError(f"initial state must be finite numbers, got {x0!r}")
    return x


@dataclass
class Trajectory:
    """Result of :func:`simulate`; arrays of shape (N,) at the sample instants t_k.

    ``x`` holds the true state (N, n) (the rig's :class:`StateLayout`); the channel arrays are what
    the acquisition measures (noise and quantisation applied when switched on); ``true`` holds the
    noise-free channels. ``i_a`` and ``v_a`` are None for a family without an armature (``esc``):
    absent, not zeros.
    """

    t: np.ndarray
    duty: np.ndarray
    x: np.ndarray
    theta: np.ndarray
    theta_dot: np.ndarray
    omega_rotor: np.ndarray
    omega_prop: np.ndarray
    thrust: np.ndarray
    i_a: np.ndarray | None = None
    v_a: np.ndarray | None = None
    true: dict[str, np.ndarray] = field(default_factory=dict)

    def channels(self) -> dict[str, np.ndarray]:
        """Measured channels keyed by the contract channel names (only those the family has)."""
        out = {
            "theta": self.theta,
            "theta_dot": self.theta_dot,
            "omega_rotor": self.omega_rotor,
            "omega_prop": self.omega_prop,
            "i_a": self.i_a,
            "v_a": self.v_a,
            "duty": self.duty,
        }
        return {k: v for k, v in out.items() if v is not None}


def _outputs(model: PlantModel, x: np.ndarray, u_eff: np.ndarray, u_before: np.ndarray
             ) -> dict[str, np.ndarray]:
    """Noise-free channels for states x (N, n) and actuator-side inputs u_eff (N,) at the samples;
    a quasi-static armature current is the one of the input held just before (``u_before``, as
    :func:`aeropend_sim.compiled.kernels.outputs`)."""
    out = model.outputs(x, u_eff)
    if model.assembly.armature and not model.dynamic_current and u_before is not u_eff:
        out["i_a"] = model.outputs(x, u_before)["i_a"]
    return out


def _quanta(rig: Rig) -> dict[str, float]:
    """LSB of each measured channel (0 = not quantised); θ̇ is estimated, never quantised."""
    s = rig.sensors
    return {"theta": s.theta_quantum, "theta_dot": 0.0, "i_a": s.i_a_quantum, "v_a": s.v_a_quantum,
            "omega_rotor": s.omega_quantum, "omega_prop": s.omega_quantum}


def _sensed(rig: Rig) -> tuple[tuple[str, float | None, float], ...]:
    """(channel, noise σ or None, quantum or 0) of each channel :meth:`PlantStepper.sample` may
    measure, in :func:`_quanta`'s order, as the rig's switches apply them: σ = the channel's RMS over
    10^(SNR/20) with sensor noise on (θ̇'s RMS 5·θ's, ω₂'s ω₁'s over the gear ratio), the quantum
    with quantisation on (and > 0)."""
    s, e = rig.sensors, rig.effects
    rms = {
        "theta": s.theta_rms, "theta_dot": s.theta_rms * 5.0, "i_a": s.i_a_rms,
        "v_a": s.v_a_rms, "omega_rotor": s.omega_rms,
        "omega_prop": s.omega_rms / rig.motor.gear_ratio,
    }
    return tuple((name, rms[name] / 10 ** (s.snr_db / 20.0) if e.sensor_noise else None,
                  q if e.quantisation and q > 0.0 else 0.0) for name, q in _quanta(rig).items())


def measure(rig: Rig, true: dict[str, np.ndarray], rng: np.random.Generator) -> dict[str, np.ndarray]:
    """Apply sensor noise (at ``rig.sensors.snr_db``) and ADC quantisation to channels.

    Noise is white Gaussian with standard deviation σ = RMS(signal)/10^(SNR/20) per channel
    (the SNR definition of thesis §5.3); quantisation rounds to the channel's LSB.

    Parameters
    ----------
    rig : Rig
    true : dict of ndarray
        Noise-free channels (``theta``, ``theta_dot``, ``i_a``, ``v_a``, ``omega_rotor``,
        ``omega_prop``).
    rng : numpy.random.Generator
        Source of the noise (seeded by the caller for reproducibility).
    """
    s, e = rig.sensors, rig.effects
    out = {}
    for name, q in _quanta(rig).items():
        if name not in true:
            continue  # a channel the family does not have
        y = true[name].copy()
        if e.sensor_noise:
            rms = float(np.sqrt(np.mean(y**2)))
            y = y + rng.normal(0.0, rms / 10 ** (s.snr_db / 20.0), size=y.shape)
        if e.quantisation and q > 0.0:
            y = np.round(y / q) * q
        out[name] = y
    return out


def _delayed_segments(
    duty: np.ndarray, dt: float, delay: float, tau_before: float
) -> tuple[np.ndarray, np.ndarray]:
    """Breakpoints and constant actuator inputs of the delayed zero-order-hold signal.

    Returns ``edges`` (M+1,) and ``values`` (M,): the actuator sees ``values[j]`` on
    [edges[j], edges[j+1]). Samples t_k are always among the edges.
    """
    n = duty.size
    t_end = n * dt
    k = np.arange(n + 1) * dt
    if delay <= 0.0:
        edges, values = k, duty
    else:
        shifted = np.arange(n) * dt + delay
        edges = np.sort(np.concatenate((k, shifted[shifted < t_end])))
        # merge breakpoints that coincide up to rounding (delay a whole number of samples)
        keep = np.concatenate(([True], np.diff(edges) > 1e-9 * dt))
        edges = edges[keep]
        mids = 0.5 * (edges[:-1] + edges[1:])
        idx = np.floor((mids - delay) / dt + 1e-9).astype(int)
        values = np.where(idx < 0, tau_before, duty[np.clip(idx, 0, n - 1)])
    return edges, values


def simulate(
    rig: Rig,
    duty: np.ndarray,
    x0: np.ndarray | None = None,
    dt: float | None = None,
    seed: int | None = 0,
    tau_before: float = 0.0,
    backend: str = DEFAULT_BACKEND,
) -> Trajectory:
    """Simulate a whole duty-cycle sequence with zero-order hold at the sample rate.

    Parameters
    ----------
    rig : Rig
        Parameters and effects.
    duty : ndarray, shape (N,)
        Duty cycle τ_k ∈ [0, 1] held over [k·dt, (k+1)·dt).
    x0 : ndarray, shape (n,) or (5,), optional
        Initial state (default: at rest, hanging down, motor off): the rig's n states
        (``plant_model(rig).states``), or the chain's five, the effects' own states then at their
        initial values (a heated winding at ambient temperature).
    dt : float, optional
        Sample period [s] (default ``rig.sample_period``).
    seed : int or None
        Seed of the measurement-noise generator (reproducible runs).
    tau_before : float
        Duty cycle the actuator sees before the first delayed command arrives.
    backend : str
        ``"compiled"`` (numba RK4, default) or ``"lsoda"`` (the reference), see the module doc.

    Returns
    -------
    Trajectory
        N samples at t_k = k·dt; sample k is the state before τ_k acts. Without an actuator lag
        the state's τ_f is the command the actuator sees at t_k; with a quasi-static armature its
        i_a is the algebraic current of the command held until t_k (before τ_k acts).

    Raises
    ------
    SimulationError
        On NaN/out-of-range duty, a bad initial state, a non-positive ``dt``, an unknown backend, or
        a compiled replay that diverges (naming the sample).
    """
    duty = _check_duty(duty)
    dt = float(rig.sample_period if dt is None else dt)
    if not dt > 0.0:
        raise SimulationError(f"sample period dt = {dt!r} must be > 0")
    model = plant_model(rig)
    x = _check_state(model, x0)
    if _check_backend(backend) == "compiled":
        return _run_compiled(CompiledPlant(model, dt), duty, x, seed, tau_before)
    states, u_at_sample, u_before = _replay_lsoda(model, duty, x, dt, tau_before)
    return _trajectory(model, dt, duty, states, u_at_sample, _outputs(model, states, u_at_sample, u_before),
                       seed)


def simulate_plant(plant: CompiledPlant, duty: np.ndarray, x0: np.ndarray | None = None,
                   seed: int | None = 0, tau_before: float = 0.0) -> Trajectory:
    """:func:`simulate` (compiled backend) on a compiled plant kept across calls: the same
    trajectory bit for bit, without building the plant again (a caller that replays one rig at one
    sample period many times, as the where-analysis does, builds it once).

    Parameters
    ----------
    plant : CompiledPlant
        The rig's compiled plant at the sample period (:func:`aeropend_sim.compiled.plant.compiled_plant`).
    duty, x0, seed, tau_before
        As :func:`simulate`'s.

    Returns
    -------
    Trajectory

    Raises
    ------
    SimulationError
        On NaN/out-of-range duty, a bad initial state, or a replay that diverges (naming the sample).
    """
    duty = _check_duty(duty)
    return _run_compiled(plant, duty, _check_state(plant.model, x0), seed, tau_before)


def _run_compiled(plant: CompiledPlant, duty: np.ndarray, x: np.ndarray, seed: int | None,
                  tau_before: float) -> Trajectory:
    """The compiled replay of checked inputs as a :class:`Trajectory`."""
    states, u, failed = plant.replay(duty, x, tau_before)
    _check_replay(plant, failed)
    true = plant.outputs(states, u, _true_channels(plant.model))
    return _trajectory(plant.model, plant.dt, duty, states, u[0], true, seed)


def _trajectory(model: PlantModel, dt: float, duty: np.ndarray, states: np.ndarray, u_at_sample: np.ndarray,
                true: dict[str, np.ndarray], seed: int | None) -> Trajectory:
    """The replay's states (τ_f and a quasi-static i_a filled in) and its measured channels."""
    if not model.lag:
        states[:, TAU_F] = u_at_sample
    if model.assembly.armature and not model.dynamic_current:
        states[:, I_A] = true["i_a"]
    meas = measure(model.rig, true, np.random.default_rng(seed))
    return Trajectory(t=np.arange(duty.size) * dt, duty=duty, x=states, thrust=true["thrust"], true=true,
                      **meas)


def _true_channels(model: PlantModel) -> tuple[str, ...]:
    """Noise-free channels of :class:`Trajectory` (those of :meth:`PlantModel.outputs`)."""
    names = ("theta", "theta_dot", "omega_rotor", "omega_prop", "thrust")
    return (*names, "i_a", "v_a") if model.assembly.armature else names


def _check_replay(plant: CompiledPlant, failed: int, p: np.ndarray | None = None, row: str = "") -> None:
    """Raise if a replay (of the rig, or of parameter vector ``p``) diverged at sample ``failed``."""
    if failed < 0:
        return
    k = int((plant.plan if p is None else plant.plans(p[None, :])).substeps[0])
    why = (f"the plant needs more than {MAX_SUBSTEPS} RK4 sub-steps per sample" if k >= MAX_SUBSTEPS else
           f"a parameter drives the plant unstable, or it is stiffer than {k} RK4 sub-steps per sample "
           f"resolve (try backend='lsoda')")
    err = SimulationError(f"{row}the compiled replay diverged at sample {failed} "
                          f"(t = {failed * plant.dt:.6g} s): a state is not finite; {why}")
    err.sample = int(failed)  # where the replay diverged (aeropend_ident.greybox.replay reads it)
    raise err


def _replay_lsoda(model: PlantModel, duty: np.ndarray, x: np.ndarray, dt: float,
                  tau_before: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """States (N, n), actuator-side commands (N,) at the samples and those just before them, LSODA
    over each stretch of constant delayed input."""
    n = duty.size
    edges, values = _delayed_segments(duty, dt, model.delay, tau_before)
    states = np.empty((n, model.states.size))
    u_at_sample = np.empty(n)
    u_before = np.empty(n)
    u_prev = float(tau_before)
    sample_t = np.arange(n) * dt
    # group consecutive equal inputs into one ODE call
    change = np.flatnonzero(np.diff(values) != 0.0) + 1
    starts = np.concatenate(([0], change))
    stops = np.concatenate((change, [values.size]))
    k = 0
    for a, b in zip(starts, stops, strict=True):
        t_grid = edges[a : b + 1]
        u = float(values[a])
        if not model.dynamic_current:
            x[I_A] = model.current(x, u)
        if not model.lag:
            x[TAU_F] = u
        # sample instants inside [t_grid[0], t_grid[-1])
        k_hi = int(np.searchsorted(sample_t, t_grid[-1] - 1e-12 * dt, side="left"))
        if k < k_hi and abs(sample_t[k] - t_grid[0]) < 1e-9 * max(dt, 1.0):
            states[k] = x
            u_at_sample[k] = u
            u_before[k] = u_prev
            k += 1
        sol = _odeint()(model.rhs, x, t_grid, args=(u,), tfirst=True, rtol=RTOL, atol=ATOL, mxstep=50000)
        # record samples that fall on interior grid points
        for j in range(1, t_grid.size - 1):
            if k < n and abs(t_grid[j] - sample_t[k]) < 1e-9 * max(dt, 1.0):
                states[k] = sol[j]
                u_at_sample[k] = u_before[k] = u
                k += 1
        x = sol[-1].copy()
        u_prev = u
    if k != n:  # pragma: no cover - guards the segment bookkeeping
        raise SimulationError(f"internal error: recorded {k} of {n} samples")
    return states, u_at_sample, u_before


def simulate_batch(
    rig: Rig | CompiledPlant,
    duty: np.ndarray,
    params: Mapping[str, Any] | np.ndarray,
    x0: np.ndarray | None = None,
    dt: float | None = None,
    tau_before: float = 0.0,
    channels: Sequence[str] = ("theta",),
    threads: int | None = None,
) -> dict[str, np.ndarray]:
    """Replay one duty-cycle sequence with many parameter sets (compiled backend, in threads).

    Row b of every result equals ``simulate(rig with the values of set b, duty, x0[b], ...,
    backend="compiled").true[channel]`` bit for bit. Measurement noise and quantisation are not
    applied (a fit compares the model's noise-free output with the data).

    Parameters
    ----------
    rig : Rig or CompiledPlant
        The rig (its values are the defaults of every parameter not varied), or a
        :class:`~aeropend_sim.compiled.plant.CompiledPlant` of it kept across calls (a fit that
        calls this hundreds of times builds it once).
    duty : ndarray, shape (N,)
        Duty cycles τ_k ∈ [0, 1].
    params : mapping or ndarray
        ``{"section.name": values (B,)}`` (an effect's parameter only when the effect is on in the
        rig), or parameter vectors (B, P) from :meth:`CompiledPlant.vectors`.
    x0 : ndarray, shape (n,) or (B, n), optional
        Initial state(s) (default at rest); the chain's five states per row also do (the effects'
        own states then at their initial values).
    dt : float, optional
        Sample period [s] (default: the rig's, or the plant's).
    tau_before : float
        Duty cycle the actuator sees before the first delayed command.
    channels : sequence of str
        Channels to return: ``theta``, ``theta_dot``, ``omega_rotor``, ``tau_f``, ``omega_prop``,
        ``thrust``, the drive quantity (``v_a``; ``omega_sp`` on an ESC) and ``i_a`` (families with
        an armature).
    threads : int, optional
        Threads the sets are shared out to (default: one per available core).

    Returns
    -------
    dict
        Channel -> ndarray (B, N).

    Raises
    ------
    SimulationError
        On a bad duty, initial state, shape or channel, or a set whose replay diverges (naming it).
    aeropend_sim.params.RigFileError
        On an unknown or switched-off parameter, or an invalid value (naming the set).
    """
    duty = _check_duty(duty)
    if isinstance(rig, CompiledPlant):
        plant = rig
        if dt is not None and float(dt) != plant.dt:
            raise SimulationError(f"dt = {dt!r} differs from the compiled plant's sample period {plant.dt}")
    else:
        plant = compiled_plant(rig, dt)
    if isinstance(params, Mapping):
        keys = tuple(params)
        p = plant.vectors(keys, np.column_stack([np.asarray(params[k], dtype=float) for k in keys])
                          if keys else np.empty((1, 0)))
    else:
        p = np.asarray(params, dtype=float)
        if p.ndim != 2 or p.shape[1] != plant.layout.size:
            raise SimulationError(f"parameter vectors of shape {p.shape}: expected (B, {plant.layout.size})")
    xs = _check_state(plant.model, x0, rows=p.shape[0])
    try:
        out, failed = plant.replay_batch(duty, p, np.ascontiguousarray(xs), tau_before, tuple(channels),
                                         threads)
    except ValueError as exc:  # an unknown channel
        raise SimulationError(str(exc)) from exc
    for b in np.flatnonzero(failed >= 0)[:1]:
        _check_replay(plant, int(failed[b]), p[b], f"parameter set {b}: ")
    return {name: out[:, c, :] for c, name in enumerate(channels)}


class PlantStepper:
    """Advance the plant one sample at a time (for the simulated plant node).

    Holds the state, the delay line of commands and the noise generator; ``step(τ)`` applies
    τ over one sample period and returns the next sample's channels. Two steppers built with
    the same rig, initial state and seed produce identical samples for identical commands.

    Parameters
    ----------
    rig : Rig
    x0 : ndarray, shape (n,) or (5,), optional
        Initial state (default at rest), as :func:`simulate` takes it.
    seed : int or None
        Seed of the measurement noise.
    backend : str
        ``"compiled"`` (default: the compiled RK4 step of :func:`simulate`, so a stepper and a batch
        simulation of the same commands give the same states bit for bit) or ``"lsoda"``.
    """

    def __init__(self, rig: Rig, x0: np.ndarray | None = None, seed: int | None = 0,
                 backend: str = DEFAULT_BACKEND) -> None:
        model = plant_model(rig)
        self.dt = rig.sample_period
        self.backend = _check_backend(backend)
        plant = CompiledPlant(model, self.dt) if backend == "compiled" else None
        # (plant, model, rig, _sensed(rig)): replaced as one by set_rig
        self._now: tuple[CompiledPlant | None, PlantModel, Rig, tuple[tuple[str, float | None, float], ...]]
        self._now = (plant, model, rig, _sensed(rig))
        self.x = _check_state(model, x0)
        self.k = 0
        self.rng = np.random.default_rng(seed)
        n_delay = self.model.delay / self.dt
        self._delay_whole = math.floor(n_delay + 1e-9)
        self._delay_frac = (n_delay - self._delay_whole) * self.dt
        self._queue: list[float] = [0.0] * (self._delay_whole + 1)
        self._u_now = 0.0

    @property
    def rig(self) -> Rig:
        """The rig being simulated."""
        return self._now[2]

    @property
    def model(self) -> PlantModel:
        """Its model."""
        return self._now[1]

    def set_rig(self, rig: Rig) -> None:
        """Continue with another rig (other effect switches, noise) from the current state, noise
        generator and pending commands: what a live parameter change of the simulated plant does.

        Raises
        ------
        ValueError
            If the sample period or the input delay differ (they size the command delay line,
            which cannot change under a running plant).
        """
        model = plant_model(rig)
        if rig.sample_period != self.dt:
            raise ValueError(f"sample period {rig.sample_period} s differs from the running {self.dt} s")
        if model.delay != self.model.delay:
            raise ValueError(f"input delay {model.delay} s differs from the running {self.model.delay} s "
                             "(it sizes the command delay line)")
        plant = CompiledPlant(model, self.dt) if self.backend == "compiled" else None
        old = self.model.states
        if model.states != old:  # an effect with a state of its own switched: keep the common states
            x = model.states.initial()
            for k, name in enumerate(model.states.names):
                if name in old.names:
                    x[k] = self.x[old.index(name)]
            self.x = x
        # one assignment: a concurrent step reads the old or the new (plant, model, rig), never a mix
        self._now = (plant, model, rig, _sensed(rig))

    def warm(self) -> None:
        """Load the compiled kernels that :meth:`step` and :meth:`sample` call, by one call of each on a
        copy of the state: the state, the delay line and the noise generator are left as they were.

        The first step of a new process otherwise loads them from the disk cache (10-15 ms; the
        plant's construction loads the sub-step planner, 0.5-1 s): a real-time caller warms the
        stepper before its first deadline (``sim_node``: before the node offers its topics).
        """
        plant = self._now[0]
        if plant is None:
            return
        x = plant.step(self.x.copy(), self._u_now, self._u_now)
        plant.outputs(x[None, :], np.array([self._u_now]))

    def sample(self) -> dict[str, float]:
        """Measured channels at the current sample instant (noise/quantisation applied)."""
        plant, model, _, sensed = self._now
        u = np.array([self._u_now])  # held over the last sample: both at and just before the instant
        # the compiled plant's outputs are the same equations (aeropend_sim.compiled.kernels.outputs),
        # a hundred times cheaper per sample than the model's array path
        x = self.x[None, :]
        return self._measure(plant.outputs(x, u) if plant is not None else _outputs(model, x, u, u), sensed)

    def _measure(self, true: Mapping[str, np.ndarray], sensed: tuple[tuple[str, float | None, float], ...]
                 ) -> dict[str, float]:
        """The channels measured from the noise-free ones ``true`` (name -> (1,) array) of the
        current instant: noise drawn and quantisation applied as ``sensed`` (:func:`_sensed` of the
        rig the plant of ``true`` simulates) says."""
        out = {}
        for name, sd, q in sensed:
            if name not in true:
                continue  # a channel the family does not have
            y = float(true[name][0])
            if sd is not None:
                y += float(self.rng.normal(0.0, sd))
            if q > 0.0:
                y = round(y / q) * q
            out[name] = y
        return out

    def step(self, duty: float) -> dict[str, float]:
        """Hold ``duty`` for one sample period and return the next sample's channels.

        Raises
        ------
        SimulationError
            If ``duty`` is NaN or outside [0, 1] (the state is left unchanged).
        """
        # a float in [0, 1] passes at once (NaN does not); anything else gets the array check's error
        if not (isinstance(duty, float) and 0.0 <= duty <= 1.0):
            _check_duty(np.array([duty]))
        self._queue.append(float(duty))
        u_old = self._queue.pop(0)  # command that was active delay_whole samples ago
        u_new = self._queue[0]
        plant, model, _, sensed = self._now
        x = self.x
        true = None
        if plant is not None:
            x = plant.step(x, u_old, u_new)
            if not all(map(math.isfinite, x.tolist())):
                self._queue.insert(0, u_old)
                self._queue.pop()
                raise SimulationError(f"the compiled step {self.k} diverged (a state is not finite): the "
                                      "plant is stiffer than its sub-steps resolve; use backend='lsoda'")
            self._u_now = u_new
            if not model.lag:
                x[TAU_F] = u_new
            if model.assembly.armature and not model.dynamic_current:
                # every channel at once: with the current quasi-static no channel reads the i_a state
                # (the current is the algebraic one), so they are those :meth:`sample` would compute
                # again from the state with its i_a set
                true = plant.outputs(x[None, :], np.array([u_new]))
                x[I_A] = true["i_a"][0]
        pieces = [(self._delay_frac, u_old), (self.dt - self._delay_frac, u_new)]
        if self._delay_whole == 0 and self._delay_frac == 0.0:
            pieces = [(self.dt, float(duty))]
        for length, u in pieces if plant is None else ():
            if length <= 0.0:
                continue
            if not model.lag:
                x[TAU_F] = u
            if not model.dynamic_current:
                x[I_A] = model.current(x, u)
            x = _odeint()(model.rhs, x, [0.0, length], args=(u,), tfirst=True, rtol=RTOL, atol=ATOL,
                       mxstep=50000)[-1].copy()
            self._u_now = u
        self.x = x
        self.k += 1
        return self.sample() if true is None else self._measure(true, sensed)
