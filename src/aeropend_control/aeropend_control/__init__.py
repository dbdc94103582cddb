"""Aeropendulum controllers (thesis chapter 6): the public API.

PID, small-signal linearisation, feedback linearisation and cascade control behind one strategy
interface (:class:`Strategy`, looked up by name in the registry), their gain design
(python-control), step metrics, and the controller node's per-sample loop without rclpy::

    from aeropend_control import ControllerLoop, Measurement, make_settings, make_strategy
    ctl = make_strategy("fl_pid", rig)
    duty = ctl.step(0.4, Measurement(theta=0.1)).duty

The rclpy node (:mod:`aeropend_control.controller_node`) is not imported here. Deeper names stay
importable from their modules; the submodules import their siblings directly, never this file.
"""

from aeropend_control.allocation import Allocation, AllocationError, ModelAllocator, ThesisAllocator
from aeropend_control.controller_core import (
    SIGNALS,
    ControllerConfigError,
    ControllerLoop,
    ControllerSettings,
    ReferenceSource,
    build_strategy,
    make_settings,
    parse_steps,
)
from aeropend_control.design import (
    CascadeDesign,
    DesignError,
    LoopDesign,
    PoleSpec,
    design_cascade,
    design_fl,
    design_small_signal,
    place_ipd,
    reachable_angle,
    reachable_grid,
    schedule,
)
from aeropend_control.drive_design import DriveSpec, design_drive, drive_model, fl_design, robust_spec
from aeropend_control.metrics import GOAL, TABLE_6_1, MetricsError, Requirements, StepMetrics, step_metrics
from aeropend_control.observer import ObserverError, ObserverSpec, PendulumObserver
from aeropend_control.pid import PID, PIDConfigError, PIDGains
from aeropend_control.strategies import (
    DEFAULT_STRATEGY,
    CascadeStrategy,
    ControlOutput,
    FeedbackLinearizationPID,
    FLCascade,
    Measurement,
    MotorCascade,
    PositionLoop,
    SmallSignalCascade,
    SmallSignalFixedPID,
    SmallSignalPID,
    Strategy,
    StrategyError,
    make_strategy,
    register,
    strategy_class,
    strategy_names,
    unregister,
)

__all__ = [
    "DEFAULT_STRATEGY",
    "GOAL",
    "PID",
    "SIGNALS",
    "TABLE_6_1",
    "Allocation",
    "AllocationError",
    "CascadeDesign",
    "CascadeStrategy",
    "ControlOutput",
    "ControllerConfigError",
    "ControllerLoop",
    "ControllerSettings",
    "DesignError",
    "DriveSpec",
    "FLCascade",
    "FeedbackLinearizationPID",
    "LoopDesign",
    "Measurement",
    "MetricsError",
    "ModelAllocator",
    "MotorCascade",
    "ObserverError",
    "ObserverSpec",
    "PIDConfigError",
    "PIDGains",
    "PendulumObserver",
    "PoleSpec",
    "PositionLoop",
    "ReferenceSource",
    "Requirements",
    "SmallSignalCascade",
    "SmallSignalFixedPID",
    "SmallSignalPID",
    "StepMetrics",
    "Strategy",
    "StrategyError",
    "ThesisAllocator",
    "build_strategy",
    "design_cascade",
    "design_drive",
    "design_fl",
    "design_small_signal",
    "drive_model",
    "fl_design",
    "make_settings",
    "make_strategy",
    "parse_steps",
    "place_ipd",
    "reachable_angle",
    "reachable_grid",
    "register",
    "robust_spec",
    "schedule",
    "step_metrics",
    "strategy_class",
    "strategy_names",
    "unregister",
]
