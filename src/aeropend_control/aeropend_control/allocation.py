"""Control allocation: desired thrust f [N] → drive quantity → duty cycle τ (no rclpy).

Two inverse chains (thesis §6.5.1 and Fig. 6.7, "h⁻¹(f)"):

* :class:`ModelAllocator` inverts the plant model's steady-state actuator chain
  (:class:`aeropend_sim.model.PlantModel`) for every actuator family: thrust f = K_q·ω₂^α
  (Eq. 3.3) → ω₂ → ω₁ = n·ω₂ (Eq. 3.4) → rotor torque balance K_t·i_a = B_m·ω₁ + K_d·ω₁² + T_c
  (steady state of the rotor equation) → v_a = R_a·i_a + K_ω·ω₁ (Eq. 3.5 at di_a/dt = 0) → τ
  from the inverse of the rig's voltage map (Eq. 4.3, ideal or an amplifier's,
  :meth:`PlantModel.duty_for_drive`); on an ESC rig ω₁ is the ESC's steady speed set-point ω_ss
  and τ comes from the inverse of its throttle map ω_ss = ω_max·((τ − τ_0)/(1 − τ_0))^β. Every
  step is the rig's own terms (their inverses, and the rotor-torque and armature terms of its
  components and switched-on effects), so a load the rig models (brush friction, drag) is in the
  inverse;
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

from aeropend_sim.model import plant_model
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
        Armature voltage [V] for ``duty`` (NaN on a family without one: ``esc``).
    duty : float
        Duty cycle τ in [0, 1].
    saturated : int
        0 = not saturated, +1 = request above the maximum (τ = 1), −1 = below the minimum.
    drive : float
        The family's drive quantity for ``duty``: v_a [V] or the ESC's rotor-speed set-point
        ω_ss [rad/s] (NaN where the allocator does not model it).
    """

    requested: float
    achieved: float
    v_a: float
    duty: float
    saturated: int
    drive: float = math.nan

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
    """Steady-state inverse of the plant model's actuator chain, for every actuator family.

    Thrust f → the rig's steady chain (:meth:`Assembly.drive_for_thrust`: thrust law⁻¹, gear⁻¹,
    then the DC motor's torque balance and armature, or the ESC's speed response) → the family's
    drive quantity q (armature voltage v_a [V] of ``dc_hbridge`` / ``voltage_amplifier``, rotor-speed
    set-point ω_ss [rad/s] of ``esc``) → duty τ through the inverse of the drive map and the duty
    terms (:meth:`PlantModel.duty_for_drive`: Eq. 4.3 or ideal H-bridge, the amplifier's
    v_offset + v_max·τ, the ESC's throttle map ω_max·((τ − τ_0)/(1 − τ_0))^β, a dead zone).

    Parameters
    ----------
    rig : Rig
        Rig whose model (with its effect switches) is inverted.

    Attributes
    ----------
    q_max : float
        Drive quantity at τ = 1 [V or rad/s].
    f_max : float
        Steady thrust at τ = 1 [N].
    v_max : float
        Armature voltage at τ = 1 [V]; NaN on a family without one (``esc``).

    Raises
    ------
    AllocationError
        If K_q ≤ 0 or the drive at full command delivers no thrust.
    """

    def __init__(self, rig: Rig) -> None:
        self.model = plant_model(rig)
        a = self.model.assembly
        if a.values["thrust.K_q"] <= 0.0:
            raise AllocationError(f"rig {rig.name!r}: K_q must be > 0 for allocation")
        self.voltage_drive = a.drive_name == "v_a"
        self.q_max = float(self.model.drive(1.0))
        self.v_max = self.q_max if self.voltage_drive else math.nan
        self.f_max = self.thrust_for_drive(self.q_max)
        if not self.f_max > 0.0:
            raise AllocationError(f"rig {rig.name!r}: full command (τ = 1, {a.drive_name} = "
                                  f"{self.q_max:.4g}) delivers no thrust")

    def drive_for_thrust(self, f: float) -> float:
        """Steady drive quantity q (v_a [V] or ω_ss [rad/s]) that produces thrust f ≥ 0 [N]."""
        return self.model.assembly.drive_for_thrust(max(float(f), 0.0))[2]

    def thrust_for_drive(self, q: float) -> float:
        """Forward steady-state chain: thrust f [N] at drive quantity q (bisection on the monotone
        inverse :meth:`drive_for_thrust`; 0 where q does not exceed the drive that holds zero thrust)."""
        if q <= self.drive_for_thrust(0.0):
            return 0.0
        lo, hi = 0.0, 1e-3
        while self.drive_for_thrust(hi) < q:
            lo, hi = hi, 2.0 * hi
            if hi > 1e9:
                raise AllocationError(f"no finite thrust reaches drive {q:.4g} "
                                      f"{self.model.assembly.drive_name}")
        for _ in range(200):
            mid = 0.5 * (lo + hi)
            lo, hi = (mid, hi) if self.drive_for_thrust(mid) < q else (lo, mid)
            if hi - lo <= 1e-13 * hi:
                break
        return 0.5 * (lo + hi)

    def _voltage_only(self, what: str) -> None:
        if not self.voltage_drive:
            raise AllocationError(f"{what}: the {self.model.family} family has no armature voltage "
                                  f"(its drive is {self.model.assembly.drive_name})")

    def voltage_for_thrust(self, f: float) -> float:
        """Steady-state armature voltage v_a [V] that produces thrust f ≥ 0 [N] (voltage families)."""
        self._voltage_only("voltage_for_thrust")
        return self.drive_for_thrust(f)

    def thrust_for_voltage(self, v_a: float) -> float:
        """Forward steady-state chain: thrust f [N] at armature voltage v_a [V] (voltage families)."""
        self._voltage_only("thrust_for_voltage")
        return self.thrust_for_drive(v_a)

    def allocate(self, f: float) -> Allocation:
        """Duty cycle for a requested thrust f [N], saturated to τ ∈ [0, 1].

        Raises
        ------
        AllocationError
            If ``f`` is not finite.
        """
        f = _check(f)
        if f <= 0.0:
            return Allocation(f, 0.0, 0.0 if self.voltage_drive else math.nan, 0.0, -1 if f < 0.0 else 0, 0.0)
        if f >= self.f_max:
            sat = 1 if f > self.f_max else 0
            return Allocation(f, self.f_max, self.v_max, 1.0, sat, self.q_max)
        q = self.drive_for_thrust(f)
        v = q if self.voltage_drive else math.nan
        return Allocation(f, f, v, self.model.duty_for_drive(min(q, self.q_max)), 0, q)


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
