"""Feedback linearisation over the motor cascade (thesis §6.8).

The FL position loop (:mod:`aeropend_control.strategies.fl_pid`) computes the thrust, the motor
speed/current PI loops (:class:`~aeropend_control.strategies.cascade.MotorCascade`) realise it.
"""

from __future__ import annotations

from aeropend_control.design import CascadeDesign, LoopDesign, PoleSpec
from aeropend_control.drive_design import fl_design
from aeropend_control.strategies.cascade import CascadeStrategy
from aeropend_control.strategies.fl_pid import FeedbackLinearizationPID
from aeropend_control.strategies.registry import register
from aeropend_sim.params import Rig


@register
class FLCascade(CascadeStrategy):
    """:class:`~aeropend_control.strategies.fl_pid.FeedbackLinearizationPID` commanding the motor
    cascade (thesis §6.8)."""

    name = "fl_cascade"
    listed = 4
    description = "feedback linearisation + I-PD over the motor speed/current PI cascade (§6.8)"
    linearising = True

    @classmethod
    def build_outer(cls, rig: Rig, spec: PoleSpec | None, cascade: CascadeDesign,
                    design: LoopDesign | None = None, **options: object) -> FeedbackLinearizationPID:
        """:class:`FeedbackLinearizationPID` with ``design`` or, if None, :func:`fl_design` of
        ``spec`` (default :meth:`default_spec_for` the rig and ``cascade``) on the cascade drive."""
        if design is None:
            design = fl_design(rig, spec or cls.default_spec_for(rig, cascade), cls.drive_for(rig, cascade))
        return FeedbackLinearizationPID(rig, design=design, **options)  # type: ignore[arg-type]
