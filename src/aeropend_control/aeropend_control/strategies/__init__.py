"""Position-control strategies of thesis chapter 6 behind one interface (no rclpy).

Every strategy is a :class:`Strategy` subclass in its own module and is looked up by name in the
registry (:mod:`~aeropend_control.strategies.registry`):

========================  =====================================================================
module                    content
========================  =====================================================================
``base``                  :class:`Strategy` (the interface), :class:`Measurement`,
                          :class:`ControlOutput`, :class:`StrategyError`
``loop``                  :class:`PositionLoop` (θ̇ estimate, PID, allocation: the I-PD loops'
                          plumbing), :class:`VelocityEstimator`
``fl_pid``                :class:`FeedbackLinearizationPID` (thesis §6.6)
``small_signal``          :class:`SmallSignalPID` (scheduled), :class:`SmallSignalFixedPID` (§6.5)
``cascade``               :class:`MotorCascade`, :class:`CascadeStrategy`,
                          :class:`SmallSignalCascade` (§6.7)
``fl_cascade``            :class:`FLCascade` (§6.8)
``registry``              :func:`register` (the one way to declare a strategy), :func:`strategy_class`,
                          :func:`make_strategy`, ... (the package's modules are discovered)
========================  =====================================================================

Usage::

    from aeropend_control.strategies import Measurement, make_strategy
    ctl = make_strategy("fl_pid", rig)              # or strategy_class("fl_pid").build(rig, spec)
    out = ctl.step(0.4, Measurement(theta=0.1))     # cascades also read omega and i_a
    out.duty
"""

from aeropend_control.strategies.base import CHANNELS, ControlOutput, Measurement, Strategy, StrategyError
from aeropend_control.strategies.cascade import (
    DETUNE_FACTOR,
    MIN_OMEGA_SPEED,
    CascadeStrategy,
    MotorCascade,
    SmallSignalCascade,
)
from aeropend_control.strategies.fl_cascade import FLCascade
from aeropend_control.strategies.fl_pid import FeedbackLinearizationPID
from aeropend_control.strategies.loop import (
    ALLOCATORS,
    DEFAULT_TF,
    ESTIMATORS,
    PositionLoop,
    VelocityEstimator,
)
from aeropend_control.strategies.registry import (
    DEFAULT_STRATEGY,
    make_strategy,
    register,
    strategy_class,
    strategy_help,
    strategy_names,
    unregister,
)
from aeropend_control.strategies.small_signal import SmallSignalFixedPID, SmallSignalPID

__all__ = [
    "ALLOCATORS",
    "CHANNELS",
    "DEFAULT_STRATEGY",
    "DEFAULT_TF",
    "DETUNE_FACTOR",
    "ESTIMATORS",
    "MIN_OMEGA_SPEED",
    "CascadeStrategy",
    "ControlOutput",
    "FLCascade",
    "FeedbackLinearizationPID",
    "Measurement",
    "MotorCascade",
    "PositionLoop",
    "SmallSignalCascade",
    "SmallSignalFixedPID",
    "SmallSignalPID",
    "Strategy",
    "StrategyError",
    "VelocityEstimator",
    "make_strategy",
    "register",
    "strategy_class",
    "strategy_help",
    "strategy_names",
    "unregister",
]
