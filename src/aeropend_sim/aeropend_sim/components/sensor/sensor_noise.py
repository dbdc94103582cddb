"""Effect ``sensor_noise``: white measurement noise at a signal-to-noise ratio (thesis §5.3).

y = y_true + N(0, σ²), σ = RMS(y_true)/10^(SNR/20) per channel (batch simulation), or
σ = (reference RMS)/10^(SNR/20) in per-sample stepping, where the RMS is not known in advance.
Applied by :func:`aeropend_sim.simulation.measure`; no term in the right-hand side.
"""

from __future__ import annotations

import math

from aeropend_sim.components.base import Effect, Param

SNR = Param("sensors.snr_db", "dB", "signal-to-noise ratio of every measured channel", absent=math.inf,
            symbol="SNR")


def _rms(name: str, unit: str, value: float, what: str) -> Param:
    return Param(f"sensors.{name}_rms", unit, f"reference RMS of {what} for the SNR in per-sample stepping",
                 sign="positive", absent=value, setting=True)


EFFECT = Effect(
    name="sensor_noise",
    part="sensors",
    label="sensor noise",
    description="y = y_true + N(0, σ²), σ = RMS(y_true)/10^(SNR/20) per channel",
    order=71,
    params=(SNR, _rms("theta", "rad", 0.4, "θ"), _rms("i_a", "A", 0.25, "i_a"), _rms("v_a", "V", 1.6, "v_a"),
            _rms("omega", "rad/s", 150.0, "ω")),
)
