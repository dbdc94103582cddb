"""A lab's experiments on the independent truth plants (bench/truth_plant.py), for the ``rig`` tests.

What a lab does with its rig before ``rig fit``: a **balance table** (hold each command until the rod
settles, average the angle over the last seconds: mean and its standard error), a **free decay**
(lift the rod, switch the motor off, record the swing once the propeller has stopped) and a
**PRBS/APRBS** run, each logged as a CSV with the angle's measurement noise. The noise-free
responses are computed once per plant (:func:`experiments`); :func:`noisy` draws one lab's noise.
"""

from __future__ import annotations

import math
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

BENCH = Path(__file__).resolve().parents[2] / "bench"
if str(BENCH) not in sys.path:
    sys.path.insert(0, str(BENCH))

import truth_plant as tp  # noqa: E402

#: Columns of the recordings' CSV logs.
CSV_HEADER = "time_s,duty,theta_rad"
#: The lab's csv_import preset file for them (docs/csv_import.md): the recordings are passed as
#: ``decay.csv:lab_log.yaml``.
PRESET = """\
# csv_import preset of the lab's logs (time in s, duty as a fraction, angle in rad, 0 = hanging)
name: lab_log
angle_col: theta_rad
angle_unit: rad
time_col: time_s
time_unit: s
input_col: duty
input_kind: duty
"""


@dataclass
class Experiments:
    """Noise-free truth of one plant: the balance levels and angles, a free decay, a PRBS run."""

    dt: float
    levels: np.ndarray
    balance: np.ndarray           # settled angle per level [rad]
    balance_samples: int          # samples averaged per level
    decay_duty: np.ndarray
    decay_theta: np.ndarray
    prbs_duty: np.ndarray
    prbs_theta: np.ndarray


def experiments(plant, dt: float, levels, hold: float = 20.0, avg: float = 2.0, lift: float = 0.6,
                prbs_seconds: float = 20.0, prbs_lo: float = 0.3, prbs_hi: float = 0.8,
                min_hold: float = 0.1, max_hold: float = 0.8, decay_seconds: float = 12.0,
                settle: float = 0.5) -> Experiments:
    """Simulate the lab's three experiments on ``plant`` (a truth plant with ``simulate(duty)``)."""
    levels = np.asarray(levels, dtype=float)
    n_hold, n_avg = round(hold / dt), round(avg / dt)
    stair = np.repeat(levels, n_hold)
    th = plant.simulate(stair)["theta_recorded"]
    balance = np.array([th[(k + 1) * n_hold - n_avg:(k + 1) * n_hold].mean() for k in range(levels.size)])
    n_lift, n_dec, n_set = round(6.0 / dt), round(decay_seconds / dt), round(settle / dt)
    duty = np.concatenate([np.full(n_lift, lift), np.zeros(n_dec + n_set)])
    dec = plant.simulate(duty)["theta_recorded"][n_lift + n_set:]
    prbs = tp.aprbs(prbs_seconds, seed=7, lo=prbs_lo, hi=prbs_hi, min_hold=min_hold, max_hold=max_hold,
                    rest=0.5, dt=dt)
    pth = plant.simulate(prbs)["theta_recorded"]
    return Experiments(dt, levels, balance, n_avg, np.zeros(dec.size), dec, prbs, pth)


def noisy(ex: Experiments, folder: Path, seed: int, sigma: float) -> dict[str, Path]:
    """One lab's files (balance.csv, decay.csv, prbs.csv, the preset lab_log.yaml) with white angle
    noise σ [rad]; ``args`` lists them as ``rig fit`` takes them."""
    rng = np.random.default_rng(seed)
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "lab_log.yaml").write_text(PRESET, encoding="utf-8")
    se = sigma / math.sqrt(ex.balance_samples)
    table = folder / "balance.csv"
    rows = ["command,angle_rad,angle_std_rad"]
    rows += [f"{c:.6g},{a + se * rng.standard_normal():.9g},{se:.6g}" for c, a in zip(ex.levels, ex.balance,
                                                                                       strict=True)]
    table.write_text("\n".join(rows) + "\n", encoding="utf-8")
    out = {"balance": table}
    runs = (("decay", ex.decay_duty, ex.decay_theta), ("prbs", ex.prbs_duty, ex.prbs_theta))
    for name, duty, theta in runs:
        y = theta + sigma * rng.standard_normal(theta.size)
        t = np.arange(theta.size) * ex.dt
        path = folder / f"{name}.csv"
        np.savetxt(path, np.column_stack([t, duty, y]), delimiter=",", header=CSV_HEADER, comments="",
                   fmt="%.9g")
        out[name] = path
    return out


def args(files: dict[str, Path]) -> list[str]:
    """The ``rig fit`` arguments of :func:`noisy`'s files (recordings with the lab's preset file)."""
    preset = files["balance"].parent / "lab_log.yaml"
    return [str(files["balance"]), f"{files['decay']}:{preset}", f"{files['prbs']}:{preset}"]
