"""The one interface every position-control strategy implements (no rclpy).

A strategy is a class derived from :class:`Strategy`. The class states what the strategy is and
needs (``name``, ``description``, ``needs``, ``default_spec``, ``drive_kind``, ``linearising``,
``required``); :meth:`Strategy.build` designs an instance for a rig; the instance runs once per
sample, :meth:`Strategy.step`, with the same signature for every strategy: the reference and a
:class:`Measurement` of the channels the rig measured, returning a :class:`ControlOutput`. The
registry (:mod:`aeropend_control.strategies.registry`) maps the ``strategy`` parameter of the
controller node to the class; the node, its launch file and the design tools read it from there.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import ClassVar, NamedTuple

from aeropend_control.design import CascadeDesign, PoleSpec
from aeropend_control.drive_design import DriveSpec, design_drive, robust_spec
from aeropend_control.observer import PendulumObserver
from aeropend_sim.params import Rig


class StrategyError(ValueError):
    """Invalid strategy configuration (the message names the value)."""


class Measurement(NamedTuple):
    """The measured channels of one sample, as a strategy receives them.

    A channel the rig does not measure (or that is missing in this sample) is NaN; a strategy reads
    only the channels its class lists in :attr:`Strategy.needs` and holds its last duty when one of
    them is not finite.

    Attributes
    ----------
    theta : float
        Rod angle θ [rad] (in the model's frame).
    omega : float
        Rotor speed ω₁ [rad/s].
    i_a : float
        Armature current i_a [A].
    """

    theta: float
    omega: float = math.nan
    i_a: float = math.nan


#: Channels a strategy may list in :attr:`Strategy.needs` (the fields of :class:`Measurement`).
CHANNELS: tuple[str, ...] = Measurement._fields


@dataclass(frozen=True)
class ControlOutput:
    """One controller sample.

    Attributes
    ----------
    duty : float
        Duty cycle τ ∈ [0, 1] to apply.
    error : float
        r − θ [rad].
    v : float
        Loop output: pseudo-control θ̈_desired [rad/s²] (FL) or thrust deviation Δf [N] (small-signal).
    thrust : float
        Requested thrust f [N] (before allocation saturation).
    theta_dot : float
        Estimated θ̇ [rad/s].
    saturated : int
        Allocation saturation (+1 high, −1 low, 0 none).
    nan_input : bool
        True if θ or r was not finite (previous duty held).
    """

    duty: float
    error: float
    v: float
    thrust: float
    theta_dot: float
    saturated: int
    nan_input: bool = False


class Strategy(ABC):
    """Base class of the position-control strategies (thesis chapter 6).

    Class attributes (what the registry, the node and the design tools read):

    name : str
        Registry key: the value of the controller node's ``strategy`` parameter. Unique.
    description : str
        One line for the parameter and launch-argument help.
    needs : tuple of str
        Measured channels (:data:`CHANNELS`) the strategy reads from :class:`Measurement`. The node
        subscribes to the armature topic only for a strategy that needs ``i_a``.
    default_spec : PoleSpec
        Closed-loop pole pattern of the position loop when the user sets none
        (:meth:`default_spec_for` adapts it to a rig file that declares its drive).
    drive_kind : str or None
        Drive the position loop commands (:data:`aeropend_control.drive_design.DRIVES`: ``"duty"``
        or ``"cascade"``), on which it is designed when the rig file declares a drive lag; None for a
        strategy without such a loop (the pole pattern is then not adapted to the rig).
    linearising : bool
        True when the position loop is feedback-linearising (it is then designed as FL).
    required : tuple of str
        Settings of :class:`~aeropend_control.controller_core.ControllerSettings` the strategy cannot
        run without (e.g. ``theta_op``); the node refuses to start without them and passes them
        to :meth:`build`.
    default : bool
        True for the one strategy the controller node runs when its ``strategy`` parameter is not
        set (``fl_pid``).
    listed : float
        Place in the registry's listing (the node's help, :func:`~.registry.strategy_names`): the
        shipped strategies 0-4; a lab's own (default ``inf``) follow in registration order.

    Instance interface: :meth:`step` once per sample, :meth:`reset`, :meth:`retune` (bumpless
    take-over of another instance's design), and the read-only :attr:`observer`,
    :attr:`nan_count` and :attr:`detune_event` the node reports.
    """

    name: ClassVar[str]
    description: ClassVar[str]
    needs: ClassVar[tuple[str, ...]] = ("theta",)
    default_spec: ClassVar[PoleSpec] = PoleSpec()
    drive_kind: ClassVar[str | None] = None
    linearising: ClassVar[bool] = False
    required: ClassVar[tuple[str, ...]] = ()
    listed: ClassVar[float] = math.inf
    default: ClassVar[bool] = False

    #: θ̂ / disturbance observer whose estimates the node publishes (None: no observer).
    observer: PendulumObserver | None = None

    @classmethod
    @abstractmethod
    def build(cls, rig: Rig, spec: PoleSpec | None = None, **options: object) -> Strategy:
        """Design an instance for ``rig``.

        Parameters
        ----------
        rig : Rig
            The model the design and the allocation use.
        spec : PoleSpec, optional
            Pole pattern of the position loop (default :meth:`default_spec_for` of ``rig``).
        **options
            Strategy options. The controller node passes ``allocator``, ``tf`` and ``estimator``
            to every strategy (a strategy without an allocation or θ̇ estimate ignores them) and
            the settings named in :attr:`required`.

        Raises
        ------
        StrategyError, DesignError
            On an invalid option or a design the rig cannot carry (both are ``ValueError``).
        """

    @abstractmethod
    def step(self, r: float, y: Measurement) -> ControlOutput:
        """One sample: reference r [rad] and the measured channels → duty (see :class:`ControlOutput`).

        A non-finite r or needed channel holds the previous duty and sets ``nan_input``.
        """

    @abstractmethod
    def reset(self) -> None:
        """Back to the initial state (the next sample starts bumpless, as the first one did)."""

    def retune(self, other: Strategy) -> None:
        """Take ``other``'s design (an instance of the same class) while running, bumpless.

        Raises
        ------
        StrategyError
            If the strategy cannot be retuned (the default) or ``other`` does not fit.
        """
        raise StrategyError(f"strategy {self.name!r} cannot be retuned while running")

    @property
    def nan_count(self) -> int:
        """Samples so far whose reference or a needed channel was not finite."""
        return 0

    @property
    def detune_event(self) -> tuple[float, float] | None:
        """(bandwidth before, after) [rad/s] when the last sample adapted an inner loop, else None
        (the cascades' motor loops, :class:`~aeropend_control.strategies.cascade.MotorCascade`)."""
        return None

    @classmethod
    def default_spec_for(cls, rig: Rig | None = None, cascade: CascadeDesign | None = None) -> PoleSpec:
        """:attr:`default_spec`; with ``rig``, its natural frequency and damping ratio chosen for
        that rig by :func:`~aeropend_control.drive_design.robust_spec` (changed only when the rig
        file declares a drive lag or delay and the strategy has a :attr:`drive_kind`; ``cascade``:
        the cascades' motor loops)."""
        if rig is None or cls.drive_kind is None:
            return cls.default_spec
        return robust_spec(rig, cls.default_spec, cls.drive_kind, cls.linearising, cascade)

    @classmethod
    def drive_for(cls, rig: Rig, cascade: CascadeDesign | None = None) -> DriveSpec | None:
        """Drive chain the position loop is designed on for ``rig``
        (:func:`~aeropend_control.drive_design.design_drive` of :attr:`drive_kind`; None without)."""
        return None if cls.drive_kind is None else design_drive(rig, cls.drive_kind, cascade)
