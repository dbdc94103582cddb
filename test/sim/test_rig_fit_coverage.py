"""The bar of issue 36: per actuator family, ``rig new`` → ``rig fit`` on a lab's simulated data of a
truth plant outside aeropend_sim (bench/fixtures/truth_plant.py) recovers the parameters within their
reported uncertainty, with the coverage checked over 20 noise seeds (at 2σ, and at the nominal 90 %
of issue 60's bar: 80-99 % of the seeds).

Each family's lab states what a lab knows (geometry, data-sheet motor constants, ...) and leaves the
rest to be fitted; the experiments (test/sim/rig_lab.py: a balance table, a free decay, a PRBS run)
are simulated once per plant and 20 labs draw their own angle noise. For every fitted parameter the
coverage is the fraction of seeds whose |fitted − true| ≤ 2σ (σ the reported standard error); a
calibrated σ gives about 95 %. The observed figures are printed (``pytest -s``) and reported in
docs/rig_command.md.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from aeropend_ident.cli.rig import main as rig_main
from aeropend_ident.greybox.rig_fit import fit_rig
from bench.fixtures import rig_lab
from bench.fixtures.rig_lab import tp

SEEDS = 20
SIGMA = 0.005  # rad, angle noise of the labs' sensors
Z90 = 1.6449  # |z| of a two-sided 90 % interval of a Gaussian estimate


@dataclass
class Case:
    family: str
    plant: object
    dt: float
    stated: list[str]
    truth: dict[str, float]
    experiments: dict


def _kq(c_t: float, diameter: float) -> float:
    return c_t * tp.RHO_AIR * diameter**4 / (2.0 * math.pi) ** 2


def esc_case() -> Case:
    p = tp.EscParams()
    rod, w_max = p.rod, p.kv_rpm * 2.0 * math.pi / 60.0 * p.battery
    return Case("esc", tp.EscPlant(p), tp.EscPlant.dt,
                [f"pendulum.mass={rod.mass}kg", f"pendulum.com_distance={rod.com * 100}cm",
                 f"pendulum.thrust_arm={rod.arm}m", "motor.gear_ratio=1", f"actuator.omega_max={w_max}rad/s"],
                {"actuator.idle_duty": (p.pulse_idle - p.pulse_min) / (p.pulse_max - p.pulse_min),
                 "actuator.curve_exponent": 1.0, "actuator.input_delay": p.dead_time, "motor.T_m": p.response,
                 "thrust.K_q": _kq(p.c_t, p.diameter), "pendulum.c_over_J": rod.damping / rod.inertia,
                 "pendulum.inertia": rod.inertia},
                {"levels": [0.2, 0.35, 0.5, 0.65, 0.8, 0.9], "prbs_seconds": 10.0, "decay_seconds": 10.0})


def dc_case() -> Case:
    p = tp.PlantParams()
    return Case("dc_hbridge", tp.TruthPlant(), tp.DT,
                [f"actuator.v_supply={p.v_supply}V", f"motor.R_a={p.R_a}ohm", f"motor.L_a={p.L_a * 1e3}mH",
                 f"motor.K_t={p.K_t}N*m/A", f"motor.K_omega={p.K_omega}V*s/rad",
                 f"motor.B_m={p.B_m}N*m*s/rad", f"motor.J_m={p.J_m}kg*m^2",
                 f"motor.gear_ratio={1.0 / tp.GEAR}", f"thrust.K_q={p.K_q}N*s^2/rad^2"],
                {"pendulum.mgd_over_J": p.mgd_over_J, "pendulum.L_over_J": p.L_over_J,
                 "pendulum.c_over_J": p.c_over_J},
                {"levels": [0.3, 0.45, 0.6, 0.75, 0.9, 1.0], "hold": 4.0, "avg": 1.0, "lift": 0.8,
                 "prbs_seconds": 8.0, "prbs_lo": 0.3, "prbs_hi": 0.95, "decay_seconds": 3.0, "settle": 0.3})


def amplifier_case() -> Case:
    p = tp.AmplifierParams()
    rod = p.rod
    return Case("voltage_amplifier", tp.AmplifierPlant(p), tp.AmplifierPlant.dt,
                [f"actuator.v_max={p.gain * p.v_ref}V", f"motor.R_a={p.R_a}ohm", f"motor.K_t={p.k_t}N*m/A",
                 f"motor.K_omega={p.k_e}V*s/rad", f"motor.B_m={p.B}N*m*s/rad",
                 f"motor.K_d={p.c_q * tp.RHO_AIR * p.diameter**5 / (2 * math.pi) ** 2}N*m*s^2/rad^2",
                 "motor.gear_ratio=1", f"pendulum.mass={rod.mass * 1e3}g",
                 f"pendulum.com_distance={rod.com}m", f"pendulum.thrust_arm={rod.arm}m"],
                {"actuator.v_offset": 0.0, "motor.J_m": p.J_r, "thrust.K_q": _kq(p.c_t, p.diameter),
                 "pendulum.c_over_J": rod.damping / rod.inertia, "pendulum.inertia": rod.inertia},
                {"levels": [0.3, 0.45, 0.6, 0.7, 0.8, 0.9], "lift": 0.7, "prbs_seconds": 10.0,
                 "prbs_lo": 0.35, "prbs_hi": 0.85, "decay_seconds": 10.0})


CASES = {"esc": esc_case, "dc_hbridge": dc_case, "voltage_amplifier": amplifier_case}


def coverage(case: Case, folder: Path, seeds: int = SEEDS) -> dict[str, dict[str, float]]:
    """Per parameter: coverage at 2σ and at the nominal 90 % (:data:`Z90` σ), seeds it was fitted on,
    median |error|/σ."""
    ex = rig_lab.experiments(case.plant, case.dt, **case.experiments)
    rig = folder / "my_rig.yaml"
    assert rig_main(["new", "--actuator", case.family, "--stated", *case.stated, "-o", str(rig)]) == 0
    hits = {k: [] for k in case.truth}
    for seed in range(seeds):
        files = rig_lab.noisy(ex, folder / f"lab{seed}", seed, SIGMA)
        res = fit_rig(rig, rig_lab.args(files))
        for k, true in case.truth.items():
            o = res.outcome(k)
            if o.status == "fitted" and math.isfinite(o.std):
                hits[k].append(abs(o.value - true) / o.std)
    out = {}
    for k, z in hits.items():
        z = np.array(z)
        out[k] = {"coverage": float(np.mean(z <= 2.0)) if z.size else 0.0,
                  "coverage90": float(np.mean(z <= Z90)) if z.size else 0.0, "fitted": int(z.size),
                  "median_z": float(np.median(z)) if z.size else math.inf}
    return out


@pytest.mark.slow
@pytest.mark.parametrize("family", sorted(CASES))
def test_rig_fit_covers_the_truth_plant(family: str, tmp_path: Path) -> None:
    case = CASES[family]()
    table = coverage(case, tmp_path)
    print(f"\n{family}: coverage of |fitted − true| ≤ 2σ and ≤ {Z90}σ (nominal 90 %) over {SEEDS} seeds")
    for k, row in table.items():
        print(f"  {k:<26} {row['coverage']:.2f}  {row['coverage90']:.2f}  (fitted on "
              f"{row['fitted']}/{SEEDS}, median |err|/σ {row['median_z']:.2f})")
    for k, row in table.items():
        assert row["fitted"] == SEEDS, f"{k} refused on {SEEDS - row['fitted']} seed(s)"
        assert row["coverage"] >= 0.8, f"{k}: coverage {row['coverage']:.2f} (expected about 0.95)"
        # issue 60's bar: a nominal 90 % interval holds the truth on 80-99 % of the seeds (1.00 would
        # be σ too wide, below 0.80 too narrow; 20 seeds give ±0.07 of binomial spread at 0.90)
        assert 0.80 <= row["coverage90"] <= 0.99, f"{k}: 90 % coverage {row['coverage90']:.2f}"
    mean = float(np.mean([r["coverage"] for r in table.values()]))
    assert mean >= 0.88, f"mean coverage {mean:.2f} (expected about 0.95)"
