"""Pure logic of the simulated plant node (no rclpy): parameter validation and scheduling.

The node :mod:`aeropend_sim.ros.sim_node` is a thin rclpy shell around this module:

* :func:`make_settings` turns the raw node parameters (whatever types ``--ros-args -p`` produced)
  into a validated :class:`SimSettings` (rig with effect overrides applied, initial state, mode,
  ...), raising :class:`SimConfigError` with a message naming the bad value and what was
  expected;
* :class:`CommandHold` is the zero-order hold of the latest valid duty command with the
  command-timeout rule of the real-time mode;
* :class:`RealtimeSchedule` is the absolute-deadline arithmetic of the real-time sampler
  (deadline of sample k, overrun detection and re-anchoring);
* :func:`sample_stamp_ns` maps a sample index to its header stamp;
* :class:`PlantClock` advances a :class:`~aeropend_sim.simulation.PlantStepper` one sample at a
  time and builds the stamped contract :class:`~aeropend_sim.contract.Sample` (both modes).

Time is integer nanoseconds throughout (``time.monotonic_ns`` for wall deadlines, ROS time for
stamps), so no floating-point drift accumulates over long runs.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from aeropend_sim.components import registry
from aeropend_sim.components.states import N_CHAIN, THETA
from aeropend_sim.contract import ContractError, Sample, validate_duty
from aeropend_sim.params import Rig, RigFileError, load_rig
from aeropend_sim.simulation import PlantStepper

#: Node modes.
MODES: tuple[str, ...] = ("realtime", "lockstep")
#: Rig the node simulates unless told otherwise.
DEFAULT_RIG = "thesis_rig"
#: Default command timeout [s] of the real-time mode (duty -> 0 after this long without command).
DEFAULT_COMMAND_TIMEOUT_S = 0.25
#: Wall-time interval [s] at which lock-step mode re-publishes its last sample while idle.
LOCKSTEP_REPUBLISH_S = 0.5

_TRUE = ("true", "1", "yes", "on")
_FALSE = ("false", "0", "no", "off")


class SimConfigError(ValueError):
    """A node parameter is invalid (unknown rig or effect, bad mode, malformed initial state...)."""


# ---------------------------------------------------------------------------------- parameters
def parse_bool(name: str, value: Any) -> bool:
    """Interpret a parameter as a boolean (``true/false``, ``1/0``, ``yes/no``, ``on/off``).

    Raises
    ------
    SimConfigError
        If ``value`` is none of those.
    """
    if isinstance(value, bool | np.bool_):
        return bool(value)
    if isinstance(value, int) and value in (0, 1):
        return bool(value)
    text = str(value).strip().lower()
    if text in _TRUE:
        return True
    if text in _FALSE:
        return False
    raise SimConfigError(f"{name} = {value!r} is not a boolean; expected true or false")


def parse_effects(items: Sequence[str] | str | None) -> dict[str, bool | str]:
    """Parse effect overrides given as ``name=value`` strings.

    Parameters
    ----------
    items : sequence of str, or str, or None
        E.g. ``["dead_zone=true", "armature_inductance=quasi_static"]``; a single string may
        hold several overrides separated by commas. ``None`` or empty means no override. The
        switches before issue 35 (``viscous_friction``, ``coulomb_friction``) are accepted and
        set every effect they stood for (rod and rotor).

    Returns
    -------
    dict
        Effect name -> value (bool, or one of the effect's modes, e.g.
        :data:`~aeropend_sim.params.INDUCTANCE_MODES` for ``armature_inductance``), in the order
        given (a later override of a name wins).

    Raises
    ------
    SimConfigError
        On an item without ``=``, an unknown effect name or an invalid value.
    """
    if items is None:
        return {}
    if isinstance(items, str):
        items = [items]
    known = {e.name: e for e in registry.effects()}
    legacy = registry.legacy_switches()
    out: dict[str, bool | str] = {}
    for raw in items:
        for item in str(raw).split(","):
            item = item.strip()
            if not item:
                continue
            name, sep, value = item.partition("=")
            name, value = name.strip(), value.strip()
            if not sep or not name or not value:
                raise SimConfigError(
                    f"effects item {item!r} is not of the form name=value (e.g. dead_zone=true)"
                )
            if name not in known and name not in legacy:
                raise SimConfigError(
                    f"unknown effect {name!r} in effects; expected one of {sorted({*known, *legacy})}")
            eff = known.get(name)
            if eff is not None and eff.modes:
                if value not in eff.modes:
                    raise SimConfigError(f"effects: {name} = {value!r}; expected one of {list(eff.modes)}")
                out[name] = value
            else:
                on = parse_bool(f"effects: {name}", value)
                out.update(dict.fromkeys(legacy.get(name, (name,)), on))
    return out


def _float_param(name: str, value: Any) -> float:
    if isinstance(value, bool) or value is None:
        raise SimConfigError(f"{name} = {value!r} is not a number")
    try:
        v = float(value)
    except (TypeError, ValueError) as exc:
        raise SimConfigError(f"{name} = {value!r} is not a number") from exc
    if not math.isfinite(v):
        raise SimConfigError(f"{name} = {value!r} is not finite")
    return v


def parse_initial_state(initial_theta: Any, initial_state: Any) -> np.ndarray:
    """Initial plant state x0: the signal chain's five states (shape (5,): θ [rad], θ̇ [rad/s], i_a [A],
    ω₁ [rad/s], τ_f [1]); an effect's own state (a winding temperature) starts at its initial value.

    Parameters
    ----------
    initial_theta : float or None
        Initial angle [rad]; the rest of the state is at rest (motor off).
    initial_state : sequence of 5 floats, or None / empty
        Full initial state; wins over ``initial_theta``, which must then be unset, 0 or equal
        to ``initial_state[0]``.

    Raises
    ------
    SimConfigError
        If ``initial_state`` does not have 5 finite numbers, or conflicts with ``initial_theta``.
    """
    theta = 0.0 if initial_theta is None else _float_param("initial_theta", initial_theta)
    if initial_state is None or (not isinstance(initial_state, str) and len(initial_state) == 0):
        x0 = np.zeros(N_CHAIN)
        x0[THETA] = theta
        return x0
    if isinstance(initial_state, str):
        raise SimConfigError(f"initial_state = {initial_state!r} must be a list of 5 numbers")
    try:
        x0 = np.asarray([float(v) for v in initial_state], dtype=float)
    except (TypeError, ValueError) as exc:
        raise SimConfigError(f"initial_state = {list(initial_state)!r} must be a list of 5 numbers") from exc
    if x0.shape != (N_CHAIN,):
        raise SimConfigError(
            f"initial_state has {x0.size} value(s) {x0.tolist()}; expected 5: "
            "[theta rad, theta_dot rad/s, i_a A, omega_rotor rad/s, tau_f 1]"
        )
    if not np.isfinite(x0).all():
        raise SimConfigError(
            f"initial_state = {x0.tolist()} has non-finite value(s); expected 5 finite numbers"
        )
    if theta != 0.0 and theta != x0[THETA]:
        raise SimConfigError(
            f"initial_theta = {theta:g} conflicts with initial_state[0] = {x0[THETA]:g}; give only one"
        )
    return x0


@dataclass(frozen=True)
class SimSettings:
    """Validated configuration of the simulated plant node.

    Attributes
    ----------
    rig : Rig
        Rig with effect overrides and the noise override applied.
    mode : str
        ``"realtime"`` or ``"lockstep"``.
    seed : int
        Seed of the measurement noise (>= 0).
    x0 : ndarray, shape (5,)
        Initial state.
    command_timeout : float
        Real-time mode: seconds without a valid command after which duty -> 0 (> 0).
    publish_clock : bool
        Publish ``/clock`` with the sample stamps.
    frame_id : str
        ``header.frame_id`` of the sample messages.
    rt_priority : int
        Real-time mode: SCHED_FIFO priority (1-99) of the sampler thread; 0 = normal scheduling.
    effect_overrides : dict
        The effect switches that were overridden (for the startup log).
    min_subscribers : int
        Lock-step mode: sample 0 is published (and the run can start) only once ``joint_states``
        has at least this many matched subscriptions (>= 1).
    min_clock_subscribers : int
        Lock-step mode with ``publish_clock``: sample 0 also waits for this many matched
        ``/clock`` subscriptions (>= 0).
    """

    rig: Rig
    mode: str
    seed: int
    x0: np.ndarray
    command_timeout: float
    publish_clock: bool
    frame_id: str
    effect_overrides: dict[str, bool | str]
    rt_priority: int = 0
    min_subscribers: int = 1
    min_clock_subscribers: int = 0

    @property
    def period_s(self) -> float:
        """Sample period [s] (``rig.sample_period``)."""
        return self.rig.sample_period


def make_settings(
    rig: Any = DEFAULT_RIG,
    effects: Any = None,
    mode: Any = "realtime",
    seed: Any = 0,
    initial_theta: Any = None,
    initial_state: Any = None,
    noise: Any = None,
    command_timeout: Any = DEFAULT_COMMAND_TIMEOUT_S,
    publish_clock: Any = None,
    frame_id: Any = "aeropend",
    rt_priority: Any = 0,
    min_subscribers: Any = 1,
    min_clock_subscribers: Any = 0,
    rig_loader: Callable[[str], Rig] = load_rig,
) -> SimSettings:
    """Validate the node parameters and build the simulation settings.

    Parameters
    ----------
    rig : str
        Shipped rig name or path to a rig YAML file.
    effects : sequence of str or None
        Effect overrides ``name=value`` (see :func:`parse_effects`).
    mode : str
        ``realtime`` or ``lockstep``.
    seed : int
        Noise seed, >= 0.
    initial_theta, initial_state :
        See :func:`parse_initial_state`.
    noise : bool or None
        Override of both ``sensor_noise`` and ``quantisation`` (None: keep the rig's switches;
        an explicit ``effects`` override of either wins over ``noise``).
    command_timeout : float
        Seconds, > 0 (real-time mode only).
    publish_clock : bool or None
        None: true in lock-step mode, false in real-time mode.
    frame_id : str
        Non-empty frame id.
    rt_priority : int
        0 (normal scheduling) or a SCHED_FIFO priority 1-99 for the real-time sampler thread.
    min_subscribers : int
        Lock-step mode: matched ``joint_states`` subscriptions needed before sample 0 (>= 1).
    min_clock_subscribers : int
        Lock-step mode: matched ``/clock`` subscriptions needed before sample 0 (>= 0; ignored
        when ``/clock`` is not published).
    rig_loader : callable
        Loads a rig by name/path (injectable for tests).

    Raises
    ------
    SimConfigError
        On any invalid parameter; the message names the parameter, its value and what was
        expected.
    """
    mode_s = str(mode).strip().lower()
    if mode_s not in MODES:
        raise SimConfigError(f"mode = {mode!r}; expected one of {list(MODES)}")
    if not isinstance(rig, str) or not rig.strip():
        raise SimConfigError(f"rig = {rig!r}; expected a rig name or a path to a .yaml rig file")
    try:
        rig_obj = rig_loader(rig.strip())
    except RigFileError as exc:
        raise SimConfigError(f"rig = {rig!r}: {exc}") from exc
    overrides: dict[str, bool | str] = {}
    if noise is not None and noise != "":
        on = parse_bool("noise", noise)
        overrides.update(sensor_noise=on, quantisation=on)
    overrides.update(parse_effects(effects))
    if overrides:
        try:
            rig_obj = rig_obj.with_effects(**overrides)
        except RigFileError as exc:  # an effect the rig's actuator family cannot have
            raise SimConfigError(f"effects: {exc}") from exc
    if isinstance(seed, bool) or not isinstance(seed, int | np.integer) or seed < 0:
        raise SimConfigError(f"seed = {seed!r}; expected an integer >= 0")
    x0 = parse_initial_state(initial_theta, initial_state)
    timeout = _float_param("command_timeout", command_timeout)
    if timeout <= 0.0:
        raise SimConfigError(f"command_timeout = {timeout:g} s; expected a duration > 0 s")
    clock = (mode_s == "lockstep") if publish_clock is None or publish_clock == "" else parse_bool(
        "publish_clock", publish_clock
    )
    if not isinstance(frame_id, str) or not frame_id.strip():
        raise SimConfigError(f"frame_id = {frame_id!r}; expected a non-empty string")
    if isinstance(rt_priority, bool) or not isinstance(rt_priority, int | np.integer) or not (
        0 <= rt_priority <= 99
    ):
        raise SimConfigError(f"rt_priority = {rt_priority!r}; expected an integer in [0, 99] (0 = off)")
    _check_count("min_subscribers", min_subscribers, 1)
    _check_count("min_clock_subscribers", min_clock_subscribers, 0)
    return SimSettings(
        rig=rig_obj, mode=mode_s, seed=int(seed), x0=x0, command_timeout=timeout, publish_clock=clock,
        frame_id=frame_id.strip(), effect_overrides=overrides, rt_priority=int(rt_priority),
        min_subscribers=int(min_subscribers), min_clock_subscribers=int(min_clock_subscribers),
    )


def _check_count(name: str, value: Any, least: int) -> None:
    """Raise :class:`SimConfigError` unless ``value`` is an integer (not a bool) >= ``least``."""
    if isinstance(value, bool) or not isinstance(value, int | np.integer) or value < least:
        raise SimConfigError(f"{name} = {value!r}; expected an integer >= {least}")


# ---------------------------------------------------------------------------------- timing
def sample_stamp_ns(k: int, period_s: float, origin_ns: int = 0) -> int:
    """Header stamp [ns] of sample k: ``origin_ns + round(k·period_s·1e9)``.

    Computed from k (not accumulated), so stamps never drift: for the thesis rig
    (T_s = 2.048 ms) sample k is stamped exactly ``origin_ns + k·2 048 000`` ns.
    """
    return int(origin_ns) + round(int(k) * float(period_s) * 1e9)


class RealtimeSchedule:
    """Absolute-deadline schedule of the real-time sampler on a monotonic clock.

    Sample k is due at ``anchor_ns + (k − anchor_k)·T``: deadlines are computed from the anchor,
    never accumulated from the previous wake-up, so sleep jitter does not accumulate. When the
    sampler wakes up more than one period after a deadline (an *overrun*: it fell behind), the
    schedule is re-anchored at the wake-up instant instead of bursting through the missed
    deadlines; the plant still advances one sample per published sample (its stamps stay on the
    k·T_s grid), so after an overrun the stamps lag the wall clock by the accumulated
    :attr:`dropped_ns`.

    Parameters
    ----------
    period_ns : int
        Sample period [ns], > 0.
    start_ns : int
        Monotonic time [ns] of sample 0's deadline.
    """

    def __init__(self, period_ns: int, start_ns: int) -> None:
        if period_ns <= 0:
            raise ValueError(f"period_ns = {period_ns} must be > 0")
        self.period_ns = int(period_ns)
        self.anchor_ns = int(start_ns)
        self.anchor_k = 0
        self.overruns = 0
        self.dropped_ns = 0
        self.max_lateness_ns = 0

    def deadline_ns(self, k: int) -> int:
        """Monotonic deadline [ns] of sample k under the current anchor."""
        return self.anchor_ns + (int(k) - self.anchor_k) * self.period_ns

    def on_wake(self, k: int, now_ns: int) -> int:
        """Account for waking up at ``now_ns`` to serve sample k; return its lateness [ns].

        If the lateness exceeds one period the overrun is counted and the schedule is
        re-anchored so that sample k is due at ``now_ns`` (later samples every period after).
        """
        late = int(now_ns) - self.deadline_ns(k)
        self.max_lateness_ns = max(self.max_lateness_ns, late)
        if late > self.period_ns:
            self.overruns += 1
            self.dropped_ns += late
            self.anchor_ns = int(now_ns)
            self.anchor_k = int(k)
        return late


class CommandHold:
    """Zero-order hold of the latest valid duty command, with validation and timeout.

    Parameters
    ----------
    timeout_ns : int or None
        After this long [ns] without a valid command the held value falls back to 0
        (None: hold forever, as in lock-step mode).
    """

    def __init__(self, timeout_ns: int | None) -> None:
        self.timeout_ns = timeout_ns
        self._last: tuple[float, int] | None = None  # (duty, receipt time); replaced atomically
        self.accepted = 0
        self.rejected = 0
        self.timeouts = 0
        self._timed_out = False

    def offer(self, value: Any, now_ns: int) -> str | None:
        """Validate and store a command received at ``now_ns``.

        Returns
        -------
        str or None
            None if accepted, else the reason (names the value and the expected range).
        """
        try:
            duty = validate_duty(value)
        except (ContractError, TypeError, ValueError) as exc:
            self.rejected += 1
            return str(exc)
        self._last = (duty, int(now_ns))
        self.accepted += 1
        return None

    def value(self, now_ns: int) -> float:
        """Duty to apply at ``now_ns``: the latest valid command, or 0 if none / timed out."""
        last = self._last
        if last is None:
            return 0.0
        duty, t = last
        if self.timeout_ns is not None and int(now_ns) - t > self.timeout_ns:
            if not self._timed_out:
                self._timed_out = True
                self.timeouts += 1
            return 0.0
        self._timed_out = False
        return duty

    @property
    def timed_out(self) -> bool:
        """True while the last :meth:`value` call fell back to 0 because of the timeout."""
        return self._timed_out


def to_sample(stamp_ns: int, channels: dict[str, float], duty: float) -> Sample:
    """Contract sample from :class:`PlantStepper` channels and the duty of the ended interval."""
    return Sample(stamp_ns=int(stamp_ns), duty=float(duty), **channels)


class PlantClock:
    """A :class:`PlantStepper` with the sample index, stamp mapping and the last sample.

    Both node modes use it: ``advance(τ)`` holds τ over one period and returns the next sample,
    stamped ``origin_ns + k·T_s``, whose ``duty``/``v_a`` describe the interval that ended at
    its stamp (wire convention of :mod:`aeropend_sim.contract`). Sample 0 carries duty 0 (the
    motor is off before the first command). Deterministic given rig, x0, seed and commands.

    Parameters
    ----------
    settings : SimSettings
    origin_ns : int
        Stamp of sample 0 [ns] (0 in lock-step mode: simulated time).
    """

    def __init__(self, settings: SimSettings, origin_ns: int = 0) -> None:
        self.stepper = PlantStepper(settings.rig, x0=settings.x0, seed=settings.seed)
        self.period_s = settings.period_s
        self.origin_ns = int(origin_ns)
        self.k = 0
        self.last = to_sample(self.stamp_ns(0), self.stepper.sample(), 0.0)

    def stamp_ns(self, k: int) -> int:
        """Stamp of sample k [ns]."""
        return sample_stamp_ns(k, self.period_s, self.origin_ns)

    def start_at(self, origin_ns: int) -> None:
        """Stamp sample 0 ``origin_ns`` [ns]: a clock built (and warmed) ahead of its start.

        Raises
        ------
        RuntimeError
            If the plant has already advanced (its stamps are out).
        """
        if self.k != 0:
            raise RuntimeError(f"the plant clock is at sample {self.k}: only sample 0 can be re-stamped")
        self.origin_ns = int(origin_ns)
        self.last = dataclasses.replace(self.last, stamp_ns=self.stamp_ns(0))

    def advance(self, duty: float) -> Sample:
        """Apply ``duty`` (already validated) for one period; return and remember the new sample."""
        channels = self.stepper.step(duty)
        self.k += 1
        self.last = to_sample(self.stamp_ns(self.k), channels, duty)
        return self.last


class CommandTiming:
    """Plant-side loop timing of the real-time mode: sample instants and command receipts.

    The sampler records, for every sample k, its stamp and the monotonic instant it was taken
    (the wake-up at its deadline, just before publishing); the command callback records the
    monotonic receipt instant of every accepted command. Both go into preallocated arrays (no
    allocation in the hot path); when ``capacity`` is reached further entries are only counted.

    :meth:`summary` attributes each command to the latest sample taken before its receipt
    (latency = receipt − that sample's instant) and counts the samples whose period ended
    without a command (``unanswered``: the plant applied a stale duty to the next period). A
    benchmark with the controller's own trace can match commands to samples exactly
    by the duty values (``bench/bench_control_latency.py``).

    Parameters
    ----------
    capacity : int
        Maximum number of samples and of commands recorded (e.g. 2^18 ≈ 9 min at 488 Hz).
    """

    def __init__(self, capacity: int = 1 << 18) -> None:
        if capacity < 1:
            raise SimConfigError(f"timing capacity = {capacity!r} must be >= 1")
        self.stamp_ns = np.zeros(capacity, dtype=np.int64)
        self.taken_ns = np.zeros(capacity, dtype=np.int64)
        self.recv_ns = np.zeros(capacity, dtype=np.int64)
        self.duty = np.zeros(capacity, dtype=np.float64)
        self.n_samples = 0
        self.n_commands = 0
        self.overflow = 0

    def on_sample(self, stamp_ns: int, taken_ns: int) -> None:
        """Sample with header stamp ``stamp_ns`` taken at monotonic ``taken_ns``."""
        k = self.n_samples
        if k < self.stamp_ns.size:
            self.stamp_ns[k] = stamp_ns
            self.taken_ns[k] = taken_ns
            self.n_samples = k + 1
        else:
            self.overflow += 1

    def on_command(self, recv_ns: int, duty: float) -> None:
        """Accepted command ``duty`` received at monotonic ``recv_ns``."""
        i = self.n_commands
        if i < self.recv_ns.size:
            self.recv_ns[i] = recv_ns
            self.duty[i] = duty
            self.n_commands = i + 1
        else:
            self.overflow += 1

    def arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(stamps, sample instants, command receipts) recorded so far [ns], copies."""
        n, m = self.n_samples, self.n_commands
        return self.stamp_ns[:n].copy(), self.taken_ns[:n].copy(), self.recv_ns[:m].copy()

    def summary(self) -> dict[str, float]:
        """Latency percentiles [ms] by latest-sample attribution and the unanswered-sample count."""
        _, taken, recv = self.arrays()
        if taken.size == 0 or recv.size == 0:
            return {"commands_timed": float(recv.size), "unanswered": math.nan}
        idx = np.searchsorted(taken, recv, side="right") - 1
        ok = idx >= 0
        lat = (recv[ok] - taken[idx[ok]]) * 1e-6
        answered = np.bincount(idx[ok], minlength=taken.size)
        lo, hi = int(idx[ok].min()), int(idx[ok].max())
        return {"commands_timed": float(lat.size), "lat_p50_ms": float(np.percentile(lat, 50)),
                "lat_p99_ms": float(np.percentile(lat, 99)), "lat_max_ms": float(lat.max()),
                "unanswered": float(np.count_nonzero(answered[lo:hi + 1] == 0))}

    def write(self, path: str) -> None:
        """Write ``path`` (.npz): ``stamp_ns``, ``taken_ns``, ``recv_ns`` (int64 ns, monotonic), ``duty``."""
        stamp, taken, recv = self.arrays()
        np.savez(path, stamp_ns=stamp, taken_ns=taken, recv_ns=recv, duty=self.duty[:recv.size].copy())
