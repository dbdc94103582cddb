"""Pure logic of the controller node (no rclpy): settings, reference, per-sample loop, trace.

:mod:`aeropend_control.controller_node` is a thin rclpy shell around :class:`ControllerLoop`.
"""

from __future__ import annotations

import csv
import itertools
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from aeropend_control.design import DesignError, PoleSpec, reachable_angle
from aeropend_control.strategies.base import ControlOutput, Measurement, Strategy, StrategyError
from aeropend_control.strategies.loop import ALLOCATORS, DEFAULT_TF, ESTIMATORS
from aeropend_control.strategies.registry import DEFAULT_STRATEGY, make_strategy, strategy_class
from aeropend_sim.params import Rig, RigFileError, load_rig
from aeropend_sim.recording_frame import RecordingFrame, read_recording_frame

MODES = ("realtime", "lockstep")
#: Column names of the internal-signal vector (``/aeropend/controller/signals`` and the trace).
#: ``recv_latency`` / ``pub_latency`` [s]: sample stamp → receipt / → command published (ROS time,
#: real-time mode only; NaN in lock-step where stamps are simulated time). ``theta_hat`` [rad] and
#: ``dist_hat`` [rad/s²]: the observer's angle and disturbance estimates (NaN with the difference
#: estimator). ``reference`` is the set point the loop used, ``reference_clamped`` 1 when the
#: requested one lay outside the rig's reach [0, :func:`~aeropend_control.design.reachable_angle`]
#: and was clamped to it, else 0. ``theta`` is the model's angle: the measured one mapped through the
#: rig file's ``recording_frame`` when it has one (:mod:`aeropend_sim.recording_frame`).
SIGNALS: tuple[str, ...] = ("t", "reference", "theta", "error", "v", "thrust", "theta_dot_hat",
                            "duty", "saturated", "stamp_s", "recv_latency", "pub_latency",
                            "theta_hat", "dist_hat", "reference_clamped")
_PUB = SIGNALS.index("pub_latency")


class ControllerConfigError(ValueError):
    """A controller parameter is invalid (the message names the value)."""


@dataclass
class ControllerSettings:
    """Validated controller-node parameters (see :func:`make_settings`)."""

    rig: Rig
    strategy: str
    mode: str
    steps: list[tuple[float, float]]
    reference: float
    allocator: str
    spec: PoleSpec
    tf: float
    theta_op: float | None
    duration: float
    trace: str
    estimator: str = "observer"
    options: dict[str, Any] = field(default_factory=dict)
    #: The rig file's ``recording_frame`` (θ_recorded = scale·(θ_model − offset)); the loop runs on θ_model.
    frame: RecordingFrame = field(default_factory=RecordingFrame)
    #: The ``rig`` parameter as given (name or path) the rig was loaded from.
    rig_file: str = "thesis_rig"
    #: The strategy's default pole pattern for this rig (:meth:`Strategy.default_spec_for`); unset
    #: pole parameters take their value from it.
    default_spec: PoleSpec = field(default_factory=PoleSpec)


def _float(name: str, value: Any) -> float:
    try:
        out = float(value)
    except (TypeError, ValueError):
        raise ControllerConfigError(f"{name} = {value!r} is not a number") from None
    if not math.isfinite(out):
        raise ControllerConfigError(f"{name} = {value!r} is not finite")
    return out


def parse_steps(value: Any) -> list[tuple[float, float]]:
    """Step sequence from a flat list [t0, θ0, t1, θ1, ...] or pairs [[t, θ], ...] ([s], [rad]).

    Raises
    ------
    ControllerConfigError
        On an odd length, non-numbers or times that are negative or not increasing.
    """
    if value is None or (isinstance(value, Sequence | str) and len(value) == 0):
        return []
    if isinstance(value, str):
        raise ControllerConfigError(f"steps = {value!r} must be a list [t0, theta0, t1, theta1, ...]")
    items = list(value)
    if all(isinstance(v, Sequence) and not isinstance(v, str) for v in items):
        flat = [x for pair in items for x in pair]
        if any(len(p) != 2 for p in items):
            raise ControllerConfigError(f"steps = {value!r}: each entry must be [t, theta]")
    else:
        flat = items
    if len(flat) % 2:
        raise ControllerConfigError(f"steps = {value!r} has odd length {len(flat)}; expected t, theta pairs")
    pairs = [(_float("steps time", flat[i]), _float("steps theta", flat[i + 1]))
             for i in range(0, len(flat), 2)]
    times = [p[0] for p in pairs]
    if times[0] < 0.0 or any(b <= a for a, b in itertools.pairwise(times)):
        raise ControllerConfigError(f"steps times {times} must be >= 0 and strictly increasing")
    return pairs


def make_settings(*, previous: ControllerSettings | None = None, **raw: Any) -> ControllerSettings:
    """Validate raw node parameters; raise :class:`ControllerConfigError` naming the bad value.

    Parameters
    ----------
    previous : ControllerSettings, optional
        Settings of the running loop. When ``raw`` names the same rig file and strategy, its rig,
        recording frame and default pole pattern are reused instead of being read and designed
        again: :meth:`Strategy.default_spec_for` runs :func:`~aeropend_control.drive_design.robust_spec` on a
        rig file that declares its drive (≈ 1 s of linear step responses), which must not happen
        inside the executor on every live ``reference`` or ``steps`` change.
    **raw
        The node's parameters (:func:`aeropend_control.controller_node.parameter_table`); missing ones
        take their defaults.
    """
    rig_file = str(raw.get("rig", "thesis_rig"))
    strategy = str(raw.get("strategy", DEFAULT_STRATEGY))
    try:
        cls = strategy_class(strategy)
    except StrategyError as exc:
        raise ControllerConfigError(str(exc)) from None
    if previous is not None and (previous.rig_file, previous.strategy) == (rig_file, strategy):
        rig, frame, base = previous.rig, previous.frame, previous.default_spec
    else:
        try:
            rig = load_rig(rig_file)
            frame = read_recording_frame(rig_file)
        except (RigFileError, OSError, ValueError) as exc:
            raise ControllerConfigError(f"rig = {raw.get('rig')!r}: {exc}") from exc
        try:
            base = cls.default_spec_for(rig)  # a pole parameter not given (None) takes the strategy's default
        except ValueError as exc:  # DesignError: e.g. a rig whose actuator cannot lift the rod
            raise ControllerConfigError(f"rig = {raw.get('rig')!r}: {exc}") from exc
    mode = str(raw.get("mode", "realtime"))
    if mode not in MODES:
        raise ControllerConfigError(f"mode = {mode!r}; expected one of {MODES}")
    allocator = str(raw.get("allocator", "model"))
    if allocator not in ALLOCATORS:
        raise ControllerConfigError(f"allocator = {allocator!r}; expected one of {ALLOCATORS}")

    def pole(name: str) -> float:
        val = raw.get(name)
        return getattr(base, name) if val is None else _float(name, val)

    spec = PoleSpec(pole("omega_n"), pole("zeta"), pole("rho"))
    try:
        spec.poles()
    except ValueError as exc:
        raise ControllerConfigError(str(exc)) from exc
    tf = _float("tf", raw.get("tf", DEFAULT_TF))
    if tf < 0.0:
        raise ControllerConfigError(f"tf = {tf!r} s must be >= 0")
    theta_op = raw.get("theta_op")
    theta_op = None if theta_op is None or (isinstance(theta_op, float) and math.isnan(theta_op)) else _float(
        "theta_op", theta_op)
    duration = _float("duration", raw.get("duration", 0.0))
    if duration < 0.0:
        raise ControllerConfigError(f"duration = {duration!r} s must be >= 0 (0 = run until stopped)")
    ref = _float("reference", raw.get("reference", 0.0))
    estimator = str(raw.get("estimator", "observer"))
    if estimator not in ESTIMATORS:
        raise ControllerConfigError(f"estimator = {estimator!r}; expected one of {ESTIMATORS}")
    settings = ControllerSettings(rig, strategy, mode, parse_steps(raw.get("steps")), ref, allocator, spec,
                                  tf, theta_op, duration, str(raw.get("trace") or ""), estimator, frame=frame,
                                  rig_file=rig_file, default_spec=base)
    missing = [name for name in cls.required if getattr(settings, name, None) is None]
    if missing:
        raise ControllerConfigError(f"strategy {strategy!r} needs {', '.join(missing)}")
    return settings


def build_strategy(s: ControllerSettings) -> Strategy:
    """The strategy object of the settings (raises :class:`ControllerConfigError` on failure).

    Every strategy gets the pole pattern, ``allocator``, ``tf`` and ``estimator``, and the
    settings its class lists in :attr:`Strategy.required`.
    """
    try:
        opts: dict[str, Any] = {"spec": s.spec, "allocator": s.allocator, "tf": s.tf,
                                "estimator": s.estimator}
        opts.update({name: getattr(s, name) for name in strategy_class(s.strategy).required})
        return make_strategy(s.strategy, s.rig, **opts)
    except ValueError as exc:
        raise ControllerConfigError(f"strategy {s.strategy!r}: {exc}") from exc


class ReferenceSource:
    """Reference θ_ref(t): the latest of the step-sequence breakpoints and topic messages.

    Parameters
    ----------
    initial : float
        Reference before any step or message [rad].
    steps : list of (t, θ)
        Breakpoints [s from the first sample], [rad].
    """

    def __init__(self, initial: float, steps: list[tuple[float, float]]) -> None:
        self.initial = initial
        self.steps = steps
        self._topic: tuple[float, float] | None = None  # (time, value)

    def set_topic(self, value: float, t: float) -> None:
        """A reference message [rad] received at sample time t [s] (ignored if not finite)."""
        if math.isfinite(value):
            self._topic = (t, float(value))

    def value(self, t: float) -> float:
        """Reference at time t [s]."""
        best_t, best = -math.inf, self.initial
        for ts, v in self.steps:
            if ts <= t:
                best_t, best = ts, v
        if self._topic is not None and self._topic[0] >= best_t:
            best = self._topic[1]
        return best


class ControllerLoop:
    """Per-sample loop: stamp handling (lock-step repeats), reference, strategy, trace.

    ``on_sample(stamp_ns, theta)`` returns the duty to publish, or None for a stale sample (older
    than the last one). A sample whose stamp equals the last one (a lock-step re-publication) is
    answered with the same command without touching the controller state.
    """

    def __init__(self, settings: ControllerSettings) -> None:
        self.settings = settings
        self.strategy = build_strategy(settings)
        try:
            #: Largest set point [rad] the rig holds with duty headroom; references are clamped to it.
            self.reach = reachable_angle(settings.rig)
        except DesignError as exc:
            raise ControllerConfigError(str(exc)) from exc
        #: (requested, used) set point when the latest sample clamped a new reference, else None
        #: (the node logs it once per change).
        self.clamp_event: tuple[float, float] | None = None
        self._clamped_from: float | None = None
        self.reference = ReferenceSource(settings.reference, settings.steps)
        self.t0_ns: int | None = None
        self.last_stamp: int | None = None
        self.last_out: ControlOutput | None = None
        self.last_signals: list[float] = []
        self.repeats = 0
        self.stale = 0
        self.rows: list[list[float]] = []

    def retune(self, settings: ControllerSettings, designed: Strategy | None = None) -> None:
        """Apply new settings while running: the pole pattern (ω_n, ζ, ρ: a new design, taken over
        bumpless, :meth:`Strategy.retune`), the
        initial reference and the step sequence (times still from the first sample). Anything else
        (rig, strategy, mode, allocator, estimator, θ_op, duration, trace, tf) is fixed for a run.

        Parameters
        ----------
        settings : ControllerSettings
        designed : strategy, optional
            ``build_strategy(settings)`` computed beforehand (the node designs a new pole pattern
            outside its executor); built here when not given and the pole pattern changed.

        Raises
        ------
        ControllerConfigError
            If a fixed setting differs or the new design fails; the loop is then unchanged.
        """
        fixed = [f for f in ("rig", "strategy", "mode", "allocator", "estimator", "theta_op", "duration",
                             "trace", "tf")
                 if getattr(settings, f) != getattr(self.settings, f)]
        if fixed:
            raise ControllerConfigError(f"{', '.join(fixed)} cannot change while the loop runs")
        if settings.spec != self.settings.spec:
            fresh = designed if designed is not None else build_strategy(settings)
            try:
                self.strategy.retune(fresh)
            except ValueError as exc:  # StrategyError, PIDConfigError
                raise ControllerConfigError(f"retune to {settings.spec}: {exc}") from exc
        self.reference.initial, self.reference.steps = settings.reference, settings.steps
        self.settings = settings

    def time_of(self, stamp_ns: int) -> float:
        """Seconds since the first sample."""
        return 0.0 if self.t0_ns is None else (stamp_ns - self.t0_ns) * 1e-9

    def done(self) -> bool:
        """True once ``duration`` (> 0) of sample time has been controlled."""
        d = self.settings.duration
        return d > 0.0 and self.last_stamp is not None and self.time_of(self.last_stamp) >= d

    @property
    def needs(self) -> tuple[str, ...]:
        """Measured channels the strategy reads (:attr:`Strategy.needs`: ``theta``, ``omega``, ``i_a``)."""
        return self.strategy.needs

    def on_sample(self, stamp_ns: int, theta: float, omega: float = math.nan,
                  i_a: float = math.nan, recv_ns: int | None = None) -> float | None:
        """Duty for a sample (see class doc); ω₁ [rad/s] and i_a [A] are read by the strategies that
        need them (:attr:`needs`).

        ``recv_ns`` is the receipt time on the stamp's clock (real-time mode), for the latency
        columns of the trace; :meth:`mark_published` fills in the publish latency.
        """
        if self.last_stamp is not None:
            if stamp_ns == self.last_stamp:
                self.repeats += 1
                return self.last_out.duty if self.last_out is not None else 0.0
            if stamp_ns < self.last_stamp:
                self.stale += 1
                return None
        if self.t0_ns is None:
            self.t0_ns = stamp_ns
        frame = self.settings.frame
        if not frame.identity:  # the rig file's sensor frame: the loop runs on the model's θ
            theta = frame.to_model(theta)
        t = self.time_of(stamp_ns)
        r_req = self.reference.value(t)
        r = min(max(r_req, 0.0), self.reach) if math.isfinite(r_req) else r_req
        clamped = r != r_req
        self.clamp_event = (r_req, r) if clamped and r_req != self._clamped_from else None
        self._clamped_from = r_req if clamped else None
        out = self.strategy.step(r, Measurement(theta, omega, i_a))
        self.last_stamp, self.last_out = stamp_ns, out
        recv = (recv_ns - stamp_ns) * 1e-9 if recv_ns is not None else math.nan
        obs = self.strategy.observer
        th_hat, d_hat = (obs.theta_k, obs.dist_k) if obs is not None else (math.nan, math.nan)
        self.last_signals = [t, r, theta, out.error, out.v, out.thrust, out.theta_dot, out.duty,
                             float(out.saturated), stamp_ns * 1e-9, recv, math.nan, th_hat, d_hat,
                             float(clamped)]
        self.rows.append(self.last_signals)
        return out.duty

    @property
    def detune_event(self) -> tuple[float, float] | None:
        """(speed-loop bandwidth before, after) [rad/s] when the last sample's duty completed a
        limit cycle of a cascade's motor loops and they were detuned
        (:attr:`Strategy.detune_event`), else None (the node logs it)."""
        return self.strategy.detune_event

    def mark_published(self, pub_ns: int) -> None:
        """Record when the command of the last new sample was published (stamp's clock)."""
        if self.last_stamp is not None and self.rows:
            self.rows[-1][_PUB] = (pub_ns - self.last_stamp) * 1e-9

    def write_trace(self, path: str | Path) -> None:
        """CSV of :data:`SIGNALS`, one row per controlled sample."""
        with open(path, "w", newline="", encoding="utf-8") as fh:
            w = csv.writer(fh)
            w.writerow(SIGNALS)
            w.writerows(self.rows)
