"""Cramér-Rao bound of the armature/rotor coefficients for several excitations (issue 4).

Why the 50 dB bar for di_a/dt is an experiment-design question: on ``thesis_sim`` the armature
and rotor equations, di_a/dt = a₁₁ i_a + a₁₂ ω₁ + b₁ v_a and dω₁/dt = a₂₁ i_a + a₂₂ ω₁, are
linear in the states with the input v_a = v_a(τ) (thesis Eq. 4.3). For a duty sequence τ_k this
script integrates the model and its output sensitivities ∂(i_a, ω₁)/∂p exactly over each
zero-order-hold sample (matrix exponential of the augmented system), forms the Fisher
information for white measurement noise on i_a and ω₁ with σ = RMS(signal)/10^(SNR/20) (the SNR
definition of :func:`aeropend_sim.simulation.measure`) and reports the Cramér-Rao bound (1σ,
relative) of every coefficient: the smallest standard error any unbiased estimator can reach
on that record. The output-error refinement reaches it (its own standard errors in
bench/results/sindy_oe*.md agree with these bounds to ~10 %).

Designs: the APRBS of the test record (holds 20-300 ms, τ 0.2-0.9), a fast APRBS (2-10 ms),
the thesis' Latin-hypercube steps, and :func:`aeropend_sim.excitation.density_modulated_prbs`
(binary 0/1 holds of 5-30 ms whose density follows a slow APRBS) at 30, 60 and 120 s; the first
75 % of each record counts (the training part).

Run: ``.venv/bin/python -m bench.bench_design_crb`` -> ``bench/results/design_crb.{json,md}``
(seconds).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
from scipy.linalg import expm

from aeropend_sim.excitation import aprbs, density_modulated_prbs, lhs_steps
from aeropend_sim.model import PlantModel
from aeropend_sim.params import Rig, load_rig

OUT = Path(__file__).resolve().parent / "results"
NAMES = ("R_a/L_a (a₁₁)", "K_ω/L_a (a₁₂)", "1/L_a (b₁)", "K_t/J_m (a₂₁)", "B_m/J_m (a₂₂)")


def electrical_matrices(rig: Rig) -> tuple[np.ndarray, np.ndarray]:
    """A (2×2) and b (2,) of d[i_a, ω₁]/dt = A [i_a, ω₁] + b v_a (viscous rotor, no drag)."""
    m = rig.motor
    a = np.array([[-m.R_a / m.L_a, -m.K_omega / m.L_a], [m.K_t / m.J_m, -m.B_m / m.J_m]])
    return a, np.array([1.0 / m.L_a, 0.0])


def cramer_rao(rig: Rig, duty: np.ndarray, snr_db: float, train: float = 0.75) -> np.ndarray:
    """Relative Cramér-Rao bound (1σ) of (a₁₁, a₁₂, b₁, a₂₁, a₂₂) on the first ``train`` of ``duty``.

    Parameters
    ----------
    rig : Rig
        Plant (its motor constants and H-bridge map v_a(τ)).
    duty : ndarray, shape (N,)
        Duty cycle per sample, zero-order hold.
    snr_db : float
        Signal-to-noise ratio of the i_a and ω₁ measurements [dB].
    train : float
        Share of the record used.

    Returns
    -------
    ndarray, shape (5,)
        Standard error / |coefficient| of each coefficient.
    """
    dt = rig.sample_period
    model = PlantModel(rig)
    v = np.array([model.armature_voltage(float(t)) for t in duty])
    a, b = electrical_matrices(rig)
    p = np.array([a[0, 0], a[0, 1], b[0], a[1, 0], a[1, 1]])
    # augmented state z = [x, ∂x/∂p₁ … ∂x/∂p₅] (12), input v_a; ∂ẋ/∂p = A ∂x/∂p + (∂A/∂p) x + (∂b/∂p) v
    big = np.zeros((13, 13))
    for k in range(6):
        big[2 * k:2 * k + 2, 2 * k:2 * k + 2] = a
    big[0:2, 12] = b
    big[2, 0] = 1.0   # a₁₁: row i_a of block 1 gets i_a
    big[4, 1] = 1.0   # a₁₂: row i_a of block 2 gets ω₁
    big[6, 12] = 1.0  # b₁:  row i_a of block 3 gets v_a
    big[9, 0] = 1.0   # a₂₁: row ω₁ of block 4 gets i_a
    big[11, 1] = 1.0  # a₂₂: row ω₁ of block 5 gets ω₁
    e = expm(big * dt)
    ad, bd = e[:12, :12], e[:12, 12]
    n = int(train * v.size)
    z = np.zeros(12)
    z[:2] = -np.linalg.solve(a, b * v[0])  # start at the equilibrium of the first level
    zs = np.empty((n, 12))
    for k in range(n):
        zs[k] = z
        z = ad @ z + bd * v[k]
    sig = [np.sqrt(np.mean(zs[:, j] ** 2)) / 10 ** (snr_db / 20.0) for j in (0, 1)]
    fisher = np.zeros((5, 5))
    for j in (0, 1):
        s = zs[:, 2 + j::2] * np.abs(p)  # relative sensitivities
        fisher += s.T @ s / sig[j] ** 2
    return np.sqrt(np.diag(np.linalg.inv(fisher)))


def designs() -> list[tuple[str, float, np.ndarray]]:
    """(name, duration [s], duty) of the compared excitations."""
    out = [("LHS steps (thesis §5.1)", 0.0, lhs_steps(10, seed=0).duty),
           ("APRBS 20-300 ms, τ 0.2-0.9 (test record)", 30.0,
            aprbs(30.0, lo=0.2, hi=0.9, min_hold=0.02, max_hold=0.3, seed=1).duty),
           ("APRBS 2-10 ms, τ 0.2-0.9", 30.0,
            aprbs(30.0, lo=0.2, hi=0.9, min_hold=0.002, max_hold=0.01, seed=1).duty)]
    for t in (30.0, 60.0, 120.0):
        out.append((f"density_prbs {t:g} s", t, density_modulated_prbs(t, seed=1).duty))
    return out


def main() -> None:
    rig = load_rig("thesis_sim")
    rows: list[dict[str, Any]] = []
    for snr in (50.0, 30.0):
        for name, _, duty in designs():
            crb = cramer_rao(rig, duty, snr)
            rows.append({"design": name, "snr_db": snr, "record_s": round(duty.size * rig.sample_period, 2),
                         "train_s": round(0.75 * duty.size * rig.sample_period, 2),
                         "crb_relative": dict(zip(NAMES, crb.tolist(), strict=True))})
            print(f"{snr:g} dB {name:42s}", " ".join(f"{100 * c:8.3f} %" for c in crb), flush=True)
    OUT.mkdir(exist_ok=True)
    (OUT / "design_crb.json").write_text(json.dumps({"rows": rows}, indent=1, ensure_ascii=False),
                                         encoding="utf-8")
    lines = ["# Cramér-Rao bound of the armature and rotor coefficients per excitation (thesis_sim)", "",
             "Written by `bench/bench_design_crb.py`: the smallest 1σ standard error (relative) any",
             "unbiased estimator can reach on the first 75 % of each record, white noise on i_a and ω₁",
             "at the given SNR.", "",
             "| SNR | design | record | " + " | ".join(NAMES) + " |", "|---|---|---|" + "---|" * len(NAMES)]
    for r in rows:
        cells = " | ".join(f"{100 * c:.3g} %" for c in r["crb_relative"].values())
        lines.append(f"| {r['snr_db']:g} dB | {r['design']} | {r['record_s']:g} s | {cells} |")
    (OUT / "design_crb.md").write_text("\n".join(lines) + "\n", encoding="utf-8")


if __name__ == "__main__":
    main()
