"""Control allocation: desired thrust f [N] → armature voltage v_a [V] → duty cycle τ (no rclpy).

Two inverse chains (thesis §6.5.1 and Fig. 6.7, "h⁻¹(f)"):

* :class:`ModelAllocator` inverts the plant model's steady-state actuator chain
  (:class:`aeropend_sim.model.PlantModel`): thrust f = K_q·ω₂^α (Eq. 3.3) → ω₂ → ω₁ = n·ω₂
  (Eq. 3.4) → rotor torque balance K_t·i_a = B_m·ω₁ + K_d·ω₁² + T_c (steady state of the rotor
  equation) → v_a = R_a·i_a + K_ω·ω₁ (Eq. 3.5 at di_a/dt = 0) → τ from the inverse of the
  rig's voltage map (Eq. 4.3 or ideal, :meth:`PlantModel.duty_for_voltage`). Every step is the
  rig's own terms (their inverses, and the rotor-torque and armature terms of its components and
  switched-on effects), so a load the rig models (brush friction, drag) is in the inverse;
* :class:`ThesisAllocator` uses the thesis' fitted static maps: the inverse of Eq. 4.4
  (f = a₂·v_a² + a₁·v_a + a₀, a₂ = 0.054 N/V², a₁ = 0.0435 N/V, a₀ = 0.0029 N) and the
  inverse of Eq. 4.3 (v_a = k0 + k1·sqrt(k2·τ + k3)).

Both are steady-state inverses: the motor/propeller dynamics (time constant ≈ 15-20 ms on the
thesis rig) are not inverted. Requests outside what τ ∈ [0, 1] can deliver are saturated and
reported in the returned :class:`Allocation`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from aeropend_sim.components.xp import MATH
from aeropend_sim.model import PlantModel
from aeropend_sim.params import Rig

#: Thesis Eq. 4.4 coefficients (a₂ [N/V²], a₁ [N/V], a₀ [N]) of f = a₂·v_a² + a₁·v_a + a₀.
EQ44 = (0.054, 0.0435, 0.0029)


class AllocationError(ValueError):
    """A non-finite thrust request or an unusable rig for allocation."""


@dataclass(frozen=True)
class Allocation:
    """Result of one allocation.

    Attributes
    ----------
    requested : float
        Requested thrust [N].
    achieved : float
        Steady-state thrust [N] the returned duty cycle produces (= requested unless saturated).
    v_a : float
        Armature voltage [V] for ``duty``.
    duty : float
        Duty cycle τ in [0, 1].
    saturated : int
        0 = not saturated, +1 = request above the maximum (τ = 1), −1 = below the minimum.
    """

    requested: float
    achieved: float
    v_a: float
    duty: float
    saturated: int

    @property
    def is_saturated(self) -> bool:
        """True if the request could not be met."""
        return self.saturated != 0


def _check(f: float) -> float:
    f = float(f)
    if not math.isfinite(f):
        raise AllocationError(f"requested thrust {f!r} N is not finite")
    return f


class ModelAllocator:
    """Steady-state inverse of the plant model's actuator chain (see module doc).

    Parameters
    ----------
    rig : Rig
        Rig whose model (with its effect switches) is inverted.
    """

    def __init__(self, rig: Rig) -> None:
        self.model = PlantModel(rig)
        a = self.model.assembly
        if not a.armature:
            raise AllocationError(f"rig {rig.name!r}: the {rig.family} family has no armature voltage to "
                                  "allocate (its drive is the ESC's speed set-point)")
        if a.values["thrust.K_q"] <= 0.0:
            raise AllocationError(f"rig {rig.name!r}: K_q must be > 0 for allocation")
        self.v_max = self.model.armature_voltage(1.0)
        self.f_max = self.thrust_for_voltage(self.v_max)

    def _inverse(self, slot: str, y: float) -> float:
        """The slot's term inverted at output y (thrust → ω₂, gear → ω₁)."""
        a = self.model.assembly
        term = a.slots[slot][-1]
        return float(term.inverse(MATH, y, *(a.by_name[p] for p in term.param_names)))

    def _current(self, v_a: float, w: float) -> float:
        """Steady armature current i_a [A] at voltage v_a and speed ω₁ (Eq. 3.5 at di_a/dt = 0)."""
        a = self.model.assembly
        return (v_a + sum(a.slot_values("armature", MATH, {"omega": w}).values())) / a.values["motor.R_a"]

    def _torque(self, i_a: float, w: float) -> float:
        """Net rotor torque [N·m]: the rig's rotor-torque terms (K_t·i_a − loads)."""
        return sum(self.model.assembly.slot_values("rotor_torque", MATH, {"i_a": i_a, "omega": w}).values())

    def voltage_for_thrust(self, f: float) -> float:
        """Steady-state armature voltage v_a [V] that produces thrust f ≥ 0 [N]."""
        a = self.model.assembly
        w1 = self._inverse("gear", self._inverse("thrust", f)) if f > 0.0 else 0.0
        vals = {**a.by_name, "i_a": 0.0, "omega": w1}
        # the rotor's torque is linear in i_a: i_a = −(torque at i_a = 0)/(∂torque/∂i_a)
        gain = sum(t.partial(MATH, "i_a", vals) for t in a.slots["rotor_torque"])
        i_a = -self._torque(0.0, w1) / gain
        return a.values["motor.R_a"] * i_a - sum(a.slot_values("armature", MATH, {"omega": w1}).values())

    def speed_for_voltage(self, v_a: float) -> float:
        """Steady-state rotor speed ω₁ [rad/s] at armature voltage v_a (bisection on the torque balance)."""

        def excess(w: float) -> float:  # motor torque − load torque, decreasing in w
            return self._torque(self._current(v_a, w), w)

        if excess(0.0) <= 0.0:
            return 0.0
        lo, hi = 0.0, 1.0
        while excess(hi) > 0.0:
            hi *= 2.0
        for _ in range(200):
            mid = 0.5 * (lo + hi)
            lo, hi = (mid, hi) if excess(mid) > 0.0 else (lo, mid)
            if hi - lo <= 1e-13 * hi:
                break
        return 0.5 * (lo + hi)

    def thrust_for_voltage(self, v_a: float) -> float:
        """Forward steady-state chain: thrust f [N] at armature voltage v_a [V]."""
        return self.model.thrust(self.speed_for_voltage(v_a))

    def allocate(self, f: float) -> Allocation:
        """Duty cycle for a requested thrust f [N], saturated to τ ∈ [0, 1].

        Raises
        ------
        AllocationError
            If ``f`` is not finite.
        """
        f = _check(f)
        if f <= 0.0:
            return Allocation(f, 0.0, 0.0, 0.0, -1 if f < 0.0 else 0)
        if f >= self.f_max:
            sat = 1 if f > self.f_max else 0
            return Allocation(f, self.f_max, self.v_max, 1.0, sat)
        v = self.voltage_for_thrust(f)
        return Allocation(f, f, v, self.model.duty_for_voltage(v), 0)


class ThesisAllocator:
    """Inverse of thesis Eqs. 4.4 (thrust vs v_a) and 4.3 (v_a vs τ).

    Parameters
    ----------
    rig : Rig
        Supplies the Eq. 4.3 coefficients k0..k3 (``rig.actuator``).
    coeffs : tuple of float
        Eq. 4.4 coefficients (a₂, a₁, a₀), default :data:`EQ44`.
    """

    def __init__(self, rig: Rig, coeffs: tuple[float, float, float] = EQ44) -> None:
        a = rig.actuator
        self.k = (a.hbridge_k0, a.hbridge_k1, a.hbridge_k2, a.hbridge_k3)
        self.a2, self.a1, self.a0 = coeffs
        if not self.a2 > 0.0:
            raise AllocationError(f"Eq. 4.4 coefficient a2 = {self.a2!r} must be > 0")
        self.v_min = max(0.0, self.voltage(0.0))
        self.v_max = self.voltage(1.0)
        self.f_min = self.thrust(self.v_min)
        self.f_max = self.thrust(self.v_max)

    def voltage(self, tau: float) -> float:
        """Eq. 4.3: v_a = k0 + k1·sqrt(k2·τ + k3) [V]."""
        k0, k1, k2, k3 = self.k
        return k0 + k1 * math.sqrt(k2 * tau + k3)

    def duty(self, v_a: float) -> float:
        """Inverse of Eq. 4.3: τ = (((v_a − k0)/k1)² − k3)/k2."""
        k0, k1, k2, k3 = self.k
        return (((v_a - k0) / k1) ** 2 - k3) / k2

    def thrust(self, v_a: float) -> float:
        """Eq. 4.4: f = a₂·v_a² + a₁·v_a + a₀ [N]."""
        return self.a2 * v_a * v_a + self.a1 * v_a + self.a0

    def voltage_for_thrust(self, f: float) -> float:
        """Inverse of Eq. 4.4 (positive root) [V]."""
        disc = self.a1 * self.a1 - 4.0 * self.a2 * (self.a0 - f)
        return (-self.a1 + math.sqrt(max(disc, 0.0))) / (2.0 * self.a2)

    def allocate(self, f: float) -> Allocation:
        """Duty cycle for a requested thrust f [N], saturated to τ ∈ [0, 1].

        Below f_min = Eq. 4.4 at the smallest voltage (a₀ = 2.9 mN at 0 V) the duty is 0 and
        the request is reported as saturated low.
        """
        f = _check(f)
        if f < self.f_min:
            return Allocation(f, self.f_min, self.v_min, 0.0, -1)
        if f > self.f_max:
            return Allocation(f, self.f_max, self.v_max, 1.0, 1)
        v = self.voltage_for_thrust(f)
        return Allocation(f, f, v, min(max(self.duty(v), 0.0), 1.0), 0)
