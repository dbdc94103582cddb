"""Component ``sensors``: the measured channels and how the angle sensor's frame may differ.

Every family measures θ (and the simulator gives θ̇, ω₁, ω₂; the voltage-driven families also
i_a and v_a, :attr:`aeropend_sim.components.base.Family.channels`). What can be wrong with the
angle sensor itself (an offset, a gain) is a measurement transform of the gap diagnosis, not a
plant parameter: θ_recorded = s·(θ_model − θ_offset), stored in a rig file's ``recording_frame``.
Noise and quantisation are the ``sensor_noise`` and ``quantisation`` effects.
"""

from __future__ import annotations

import math

from aeropend_sim.components.base import POSITIVE, Component, Diagnosis, Search

COMPONENT = Component(
    name="sensors",
    part="sensors",
    label="sensors",
    description="θ (and θ̇, ω₁, ω₂, i_a, v_a where the family has them) sampled every T_s",
    order=70,
    diagnoses=(
        Diagnosis("sensor_offset", "sensor", "angle-sensor offset: θ_recorded = θ − θ_offset",
                  ("theta_offset",),
                  ("theta",), sindy_terms={"theta_dot": ("−(mgd/J)·cos θ",)},
                  truth={"theta_offset": ((-0.1, -0.04), (0.04, 0.1))}, kind="measurement", order=200,
                  search=(Search("theta_offset", "rad", (-math.pi, math.pi), "measurement.theta_offset",
                                 "θ_model − θ_recorded", lambda ctx: (-0.6, 0.6, 0.0, 0.05), "±0.6"),)),
        Diagnosis("sensor_scale", "sensor", "angle-sensor gain error: θ_recorded = s·θ", ("theta_scale",),
                  ("theta",),
                  sindy_terms={"theta_dot": ("s·θ̈_model(θ/s)",)},
                  confusable_with=("gravity", "thrust_coefficient", "inertia"),
                  truth={"theta_scale": ((0.86, 0.93), (1.07, 1.14))}, kind="measurement", order=210,
                  search=(Search("theta_scale", "1", POSITIVE, "measurement.theta_scale", "sensor gain s",
                                 lambda ctx: (0.5, 2.0, 1.0, 1.1), "0.5 … 2", log=True),)),
    ),
)
