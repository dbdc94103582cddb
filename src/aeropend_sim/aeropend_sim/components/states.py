"""The plant's state vector: one home for what each entry is and where it sits.

Every rig has the five states of the signal chain (:data:`CHAIN`), declared here because the
chain's skeleton (:mod:`aeropend_sim.components.assembly`) integrates them whatever the family:
the rod angle and rate, the armature current (≡ 0 on a family without an armature), the rotor
speed and the actuator-lag state (= τ without a lag). An effect may declare states of its own
(:attr:`aeropend_sim.components.base.Part.states`, e.g. ``motor_heating``'s winding temperature
rise T_m); a rig on which that effect acts has them after the chain's, in the effects' order, and
each has one ``rate`` term giving its derivative. The state vector of a rig is its
:class:`StateLayout` (:attr:`aeropend_sim.model.PlantModel.states`): code asks the layout for an
index by name (``layout.index("i_a")``), never writes a position.

The chain's states keep their positions on every layout (0-4), so :data:`THETA` … :data:`TAU_F`
index any rig's state, and an array of a rig without effect states is what it was before effect
states existed.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np


@dataclass(frozen=True)
class State:
    """One entry of the plant's state vector.

    Attributes
    ----------
    name : str
        Public name (channel and table name, ``"omega_rotor"``); for an effect's state also the
        argument name its terms read it by.
    symbol : str
        Symbol for tables (``"ω₁"``).
    unit : str
        SI unit.
    description : str
        Meaning (one line).
    variable : str
        Name in the generated equations and the terms' argument name (default: :attr:`name`; the
        chain's rotor speed is ``omega``).
    initial : float
        Value where nothing else is known: a simulation's or a replay's start when the caller gives
        only the chain's states (a recording measures none of an effect's states), and the value the
        chain's steady states (:meth:`~aeropend_sim.components.assembly.Assembly.steady_state`) hold
        it at (T_m = 0: the motor at ambient temperature).
    typical : float
        A magnitude it typically reaches on a lab's rig (its unit), for scales and tests.
    """

    name: str
    symbol: str
    unit: str
    description: str
    variable: str = ""
    initial: float = 0.0
    typical: float = 1.0

    def __post_init__(self) -> None:
        if not self.name.isidentifier():
            raise ValueError(f"state name {self.name!r} must be an identifier")
        if not self.variable:
            object.__setattr__(self, "variable", self.name)


#: The signal chain's states, in their fixed positions.
CHAIN: tuple[State, ...] = (
    State("theta", "θ", "rad", "pendulum angle from the vertical (0 = hanging down)"),
    State("theta_dot", "θ̇", "rad/s", "pendulum angular velocity Ω"),
    State("i_a", "i_a", "A", "armature current (≡ 0 on a family without an armature: esc)"),
    State("omega_rotor", "ω₁", "rad/s", "rotor speed (motor side of the gearbox)", variable="omega"),
    State("tau_f", "τ_f", "1", "duty cycle after the first-order actuator lag (= τ without lag)"),
)


@dataclass(frozen=True)
class StateLayout:
    """The state vector of one rig: the chain's states, then its active effects' own states.

    Attributes
    ----------
    states : tuple of State
    """

    states: tuple[State, ...]

    @classmethod
    def of(cls, extra: Iterable[State] = ()) -> StateLayout:
        """The chain's states followed by ``extra``.

        Raises
        ------
        ValueError
            If a name repeats (two effects declaring one state, or one named like a chain state).
        """
        states = (*CHAIN, *extra)
        names = [s.name for s in states] + [s.variable for s in states if s.variable != s.name]
        dup = sorted({n for n in names if names.count(n) > 1})
        if dup:
            raise ValueError(f"state name(s) {dup} declared twice")
        return cls(states)

    @property
    def size(self) -> int:
        """Length of the state vector."""
        return len(self.states)

    @property
    def names(self) -> tuple[str, ...]:
        """Names in order."""
        return tuple(s.name for s in self.states)

    @property
    def extra(self) -> tuple[State, ...]:
        """The effects' states (after the chain's)."""
        return self.states[len(CHAIN):]

    @property
    def extra_names(self) -> tuple[str, ...]:
        """Names of the effects' states: what a compiled module is generated for
        (:func:`aeropend_sim.compiled.source.family_module`)."""
        return tuple(s.name for s in self.extra)

    def index(self, name: str) -> int:
        """Position of the state called ``name`` (its name or its variable).

        Raises
        ------
        KeyError
            If this rig has no such state (the message lists the ones it has).
        """
        for k, s in enumerate(self.states):
            if name in (s.name, s.variable):
                return k
        raise KeyError(f"no state {name!r} on this rig; its states are {list(self.names)}")

    def initial(self) -> np.ndarray:
        """Every state at its :attr:`State.initial` value, shape (size,)."""
        return np.array([s.initial for s in self.states])

    def complete(self, x: Any, what: str = "initial state") -> np.ndarray:
        """``x`` as a whole state: a state of the layout as it is, or the chain's five states with
        the effects' states appended at their initial values. Works on a row (n,) or rows (B, n).

        Raises
        ------
        ValueError
            If the last axis is neither the layout's size nor the chain's (naming both).
        """
        x = np.asarray(x, dtype=float)
        if x.ndim >= 1 and x.shape[-1] == self.size:
            return x
        if x.ndim >= 1 and x.shape[-1] == len(CHAIN):
            tail = np.broadcast_to(self.initial()[len(CHAIN):], (*x.shape[:-1], self.size - len(CHAIN)))
            return np.concatenate([x, tail], axis=-1)
        raise self._refused(x.shape, what)

    def with_values(self, x: Any, values: Mapping[str, float] | None, what: str = "initial state"
                    ) -> np.ndarray:
        """One state ``x`` completed as :meth:`complete` completes it, with the named states set to
        ``values`` (a winding temperature carried over from an earlier part of the run); None or an
        empty mapping leaves it as completed.

        Raises
        ------
        KeyError
            On a name that is not a state of this layout (naming its states).
        ValueError
            As :meth:`complete`.
        """
        out = np.array(self.complete(x, what), dtype=float)
        for name, value in (values or {}).items():
            out[..., self.index(name)] = value
        return out

    def whole(self, x: Any, what: str = "state") -> list[float]:
        """One state as a list of floats (the scalar evaluators' form), completed as
        :meth:`complete` completes an array, without building one.

        Raises
        ------
        ValueError
            As :meth:`complete`.
        """
        xs = [float(v) for v in x]
        if len(xs) == len(CHAIN) < self.size:
            xs += [s.initial for s in self.extra]
        elif len(xs) != self.size:
            raise self._refused((len(xs),), what)
        return xs

    def _refused(self, shape: tuple[int, ...], what: str) -> ValueError:
        return ValueError(f"{what} of shape {shape}: expected {self.size} states {list(self.names)} or the "
                          f"chain's {len(CHAIN)} (the effects' states then start at their initial values)")


#: The chain's layout (a rig without effect states).
CHAIN_LAYOUT = StateLayout.of()
THETA, THETA_DOT, I_A, OMEGA, TAU_F = (CHAIN_LAYOUT.index(n) for n in
                                       ("theta", "theta_dot", "i_a", "omega_rotor", "tau_f"))
#: Size of the chain's state (every rig has at least these).
N_CHAIN = CHAIN_LAYOUT.size
