"""Reproduce the derived numbers of ``thesis_rig.yaml`` from the thesis' own data.

Run: ``python tools/derive_thesis_rig.py``. Prints the motor constants fitted to thesis
Table 4.2, the thrust coefficient from Eq. 4.4, and the pendulum (mgd/J, c/J, L/J) fitted so
that the full model's open-loop step at τ = 43.14 % has the rig's measured metrics
(thesis §6.2: tr 0.43 s, tp 0.84 s, ts 3.53 s, θss 0.54 rad). Step metrics use
python-control's definitions (rise 10-90 %, settling 2 %). See docs/parameters.md.
"""

from __future__ import annotations

import math

import control
import numpy as np
from scipy.optimize import least_squares

from aeropend_sim.params import load_rig
from aeropend_sim.simulation import simulate

# thesis Table 4.2: v_a [V], i_a [A], rotor speed [RPM] (strobe on the propeller × gear ratio)
TABLE_4_2 = np.array([
    [1.08, 0.29, 1158], [1.182, 0.33, 1235], [1.272, 0.35, 1306], [1.377, 0.40, 1402],
    [1.483, 0.45, 1485], [1.561, 0.50, 1561], [1.666, 0.55, 1638], [1.781, 0.61, 1734],
    [1.864, 0.65, 1805], [1.974, 0.70, 1885],
])
R_A = 1.08  # Table 4.1
GEAR = 55 / 9  # rotor turns faster than the propeller
STEP = {"tau": 0.4314, "RiseTime": 0.43, "PeakTime": 0.84, "SettlingTime": 3.53, "theta_ss": 0.54}


def motor_constants() -> dict[str, float]:
    """K_ω, B_m, K_d and K_q from Table 4.2 and Eq. 4.4."""
    v, i, rpm = TABLE_4_2.T
    k_rpm = (v - R_A * i) / rpm
    k_w = float(k_rpm.mean() * 60 / (2 * math.pi))
    w1 = rpm * 2 * math.pi / 60
    (b_m, k_d), *_ = np.linalg.lstsq(np.c_[w1, w1**2], k_w * i, rcond=None)
    f = 0.054 * v**2 + 0.0435 * v + 0.0029  # Eq. 4.4
    w2 = w1 / GEAR
    k_q = float(np.sum(f * w2**2) / np.sum(w2**4))
    return {"K_omega [V*s/rad]": k_w, "K_omega [V/RPM]": float(k_rpm.mean()),
            "sigma [V/RPM]": float(k_rpm.std(ddof=1)), "B_m": float(b_m), "K_d": float(k_d),
            "K_q": k_q, "J_m": k_w / 4519.2}


def step_metrics(rig, duration: float = 8.0) -> dict[str, float]:
    n = int(duration / rig.sample_period)
    traj = simulate(rig, np.full(n, STEP["tau"]))
    info = control.step_info(traj.theta, traj.t, SettlingTimeThreshold=0.02, RiseTimeLimits=(0.1, 0.9))
    return {"RiseTime": info["RiseTime"], "PeakTime": info["PeakTime"],
            "SettlingTime": info["SettlingTime"], "theta_ss": float(traj.theta[-1])}


def fit_pendulum() -> tuple[dict[str, float], dict[str, float]]:
    rig0 = load_rig("thesis_sim")  # valid file whose motor, thrust and pendulum are replaced
    rig0 = _thesis_rig_motor(rig0)

    f_ss, _ = _eq_thrust(rig0)

    def with_pend(p: np.ndarray):
        a_g, a_c = np.exp(p)
        # L/J from the steady state: (L/J)·f_ss = (mgd/J)·sin θss
        b_f = a_g * math.sin(STEP["theta_ss"]) / f_ss
        return rig0.with_params("pendulum", mgd_over_J=a_g, c_over_J=a_c, L_over_J=b_f)

    def residual(p: np.ndarray) -> np.ndarray:
        m = step_metrics(with_pend(p))
        return np.array([m[k] / STEP[k] - 1.0 for k in ("RiseTime", "PeakTime", "SettlingTime")])

    sol = least_squares(residual, np.log([20.0, 2.0]), x_scale=1.0, diff_step=1e-3)
    rig = with_pend(sol.x)
    p = rig.pendulum
    return ({"mgd_over_J": p.mgd_over_J, "c_over_J": p.c_over_J, "L_over_J": p.L_over_J},
            step_metrics(rig))


def _thesis_rig_motor(rig):
    c = motor_constants()
    rig = rig.with_params("motor", R_a=R_A, L_a=2.2e-3, K_omega=c["K_omega [V*s/rad]"],
                          K_t=c["K_omega [V*s/rad]"], J_m=c["J_m"], B_m=c["B_m"], K_d=c["K_d"],
                          gear_ratio=GEAR)
    rig = rig.with_params("thrust", K_q=c["K_q"])
    return rig.with_effects(propeller_drag=True, hbridge_map=True)


def _eq_thrust(rig) -> tuple[float, float]:
    """Steady thrust [N] at the step duty (motor steady state under Eq. 4.3 voltage)."""
    n = int(1.0 / rig.sample_period)
    traj = simulate(rig.with_params("pendulum", mgd_over_J=1e3, c_over_J=100.0), np.full(n, STEP["tau"]))
    return float(traj.thrust[-1]), float(traj.v_a[-1])


if __name__ == "__main__":
    for k, v in motor_constants().items():
        print(f"{k:>20s} = {v:.5g}")
    pend, metrics = fit_pendulum()
    for k, v in pend.items():
        print(f"{k:>20s} = {v:.5g}")
    print("step metrics of the fitted model:", {k: round(v, 3) for k, v in metrics.items()})
    print("targets:", STEP)
