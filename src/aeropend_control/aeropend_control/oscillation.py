"""Detection of a sustained oscillation (limit cycle) in a loop's output, per sample (no rclpy).

A feedback loop whose crossover is too fast for dynamics the rig file does not know (a drive lag,
a delay) does not go unstable without bound on the rig: the actuator limits turn it into a
sustained oscillation of nearly constant amplitude and period — the relay-feedback experiment of
Åström & Hägglund (*Automatica* 20(5), 1984), run by accident. Its signature in the loop output u
is a fast, large swing around its own mean, which a step response does not show: a step drives u
into one limit and back once or twice, then u settles.

:class:`OscillationMonitor` counts alternations of u between ``u > ū + A`` and ``u < ū − A``
(hysteresis band of half-width A around the exponential moving average ū with time constant T_m)
and reports a limit cycle when at least N alternations fall within a window W. With the defaults
(A = 0.2 duty, T_m = 0.3 s, N = 8 within W = 1 s, i.e. four full swings of at least 0.4 duty peak to
peak faster than 4 Hz) the thesis' cascade on its nominal rig never triggers (steps, 10 ms lag +
5 ms delay, 50 dB noise), while the 6-8 Hz cycles of a 40-60 ms drive lag trigger within about a
second (measured in docs/control.md, "Cascade limit cycles: detection and detuning").
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass


@dataclass(frozen=True)
class OscillationSettings:
    """Thresholds of :class:`OscillationMonitor`.

    Attributes
    ----------
    amplitude : float
        Half-width A of the hysteresis band around the moving average [output unit, e.g. duty].
    mean_time_constant : float
        Time constant T_m of the moving average ū [s].
    alternations : int
        Alternations N (crossings from one side of the band to the other) that make a cycle.
    window : float
        Window W [s] in which the N alternations must fall.
    """

    amplitude: float = 0.2
    mean_time_constant: float = 0.3
    alternations: int = 8
    window: float = 1.0

    def validate(self) -> None:
        """Raise ``ValueError`` naming the first non-positive or non-finite setting."""
        for name in ("amplitude", "mean_time_constant", "window"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0.0):
                raise ValueError(f"oscillation {name} = {v!r} must be finite and > 0")
        if self.alternations < 2:
            raise ValueError(f"oscillation alternations = {self.alternations!r} must be >= 2")


class OscillationMonitor:
    """Per-sample limit-cycle detector of a loop output (see the module docstring).

    Parameters
    ----------
    dt : float
        Sample period [s].
    settings : OscillationSettings, optional

    Raises
    ------
    ValueError
        On a non-positive ``dt`` or invalid settings.
    """

    def __init__(self, dt: float, settings: OscillationSettings | None = None) -> None:
        if not (math.isfinite(dt) and dt > 0.0):
            raise ValueError(f"oscillation monitor dt = {dt!r} must be finite and > 0")
        self.settings = settings or OscillationSettings()
        self.settings.validate()
        self.dt = float(dt)
        self._alpha = 1.0 - math.exp(-self.dt / self.settings.mean_time_constant)
        self.reset()

    def reset(self) -> None:
        """Forget the history (the moving average restarts from the next sample)."""
        self.mean: float | None = None
        self.side = 0
        self.k = 0
        self._flips: deque[int] = deque()

    def update(self, u: float) -> bool:
        """Take one output sample; True when a limit cycle is detected at this sample.

        After a detection the history is cleared, so the next report needs N new alternations.
        Non-finite samples are ignored.
        """
        if not math.isfinite(u):
            return False
        self.k += 1
        s = self.settings
        self.mean = u if self.mean is None else self.mean + self._alpha * (u - self.mean)
        side = 1 if u > self.mean + s.amplitude else (-1 if u < self.mean - s.amplitude else 0)
        if side != 0 and side != self.side:
            if self.side != 0:
                self._flips.append(self.k)
            self.side = side
        horizon = self.k - s.window / self.dt
        while self._flips and self._flips[0] < horizon:
            self._flips.popleft()
        if len(self._flips) >= s.alternations:
            self._flips.clear()
            self.side = 0
            return True
        return False
