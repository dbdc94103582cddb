"""Benchmark: closed-loop steps of every strategy on the thesis rig (batch, in-process).

Each registered strategy (:mod:`aeropend_control.strategies`) that needs no extra setting × steps
from rest (θ = 0) to 0.2, 0.4 and 0.7 rad, 4 s, controller at every 2.048 ms sample, plant simulated by
:class:`aeropend_sim.simulation.PlantStepper` (the same stepper the lock-step ``sim_node`` runs;
``test/ros/control/test_controller.py`` checks that the ROS loop reproduces this loop sample by sample).
Scenarios:

* ``nominal``: the nominal ``thesis_rig``;
* ``noise_50dB``: sensor noise at 50 dB SNR on the measured channels (θ noise σ ≈ 1.3 mrad);
  metrics are computed on the **true** θ (the physical response), the controller sees the noisy θ;
* ``unmodelled``: effects the design model lacks, with assumed magnitudes (the thesis measured
  none of them): dead zone τ_dz = 0.03, rotor Coulomb friction T_c = 2e-5 N·m, rod Coulomb
  friction 0.2 rad/s², first-order actuator lag T_a = 10 ms, input delay 5 ms.

Controllers use their defaults (θ̇ from the Kalman observer of
:mod:`aeropend_control.observer`); ``estimator_comparison`` repeats every cell with the filtered
difference estimator (``estimator="difference"``, T_f = 10 ms) for comparison.

Also a time-optimal reference: the minimum time to move the **ideal-thrust** pendulum (thrust
switched instantly between 0 and f_max = thrust at τ = 1, motor dynamics ignored) from rest at
0 to rest at θ_ref (one switch, bang-bang), a lower bound for any controller's settling time;
``ts_ratio`` = ts / that bound.

The same cells over ROS: ``bench/bench_control_ros.py``. Plots of θ and τ per run:
``bench/results/control_<scenario>.png``.

Writes ``bench/results/control.json`` and prints a table. Run:
``.venv/bin/python -m bench.bench_control``
"""

from __future__ import annotations

import json
import math
import platform
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
from scipy.integrate import solve_ivp
from scipy.optimize import brentq

from aeropend_control.allocation import ModelAllocator
from aeropend_control.metrics import GOAL, TABLE_6_1, step_metrics
from aeropend_control.strategies import Measurement, make_strategy, strategy_class, strategy_names
from aeropend_sim.model import THETA, PlantModel
from aeropend_sim.params import Rig, load_rig
from aeropend_sim.simulation import PlantStepper

OUT = Path(__file__).resolve().parent / "results" / "control.json"
SETPOINTS = (0.2, 0.4, 0.7)
HORIZON_S = 4.0
#: Registered strategies that run without an extra setting (not ``small_signal_fixed``: it needs θ_op).
BENCH_STRATEGIES = tuple(s for s in strategy_names() if not strategy_class(s).required)


def scenarios() -> dict[str, Rig]:
    """The three plant variants (see module doc)."""
    nominal = load_rig("thesis_rig")
    noisy = nominal.with_effects(sensor_noise=True)
    unmod = (
        nominal.with_params("actuator", dead_zone=0.03, lag_time_constant=0.01, input_delay=0.005)
        .with_params("motor", T_c=2e-5)
        .with_params("pendulum", coulomb_over_J=0.2)
        .with_effects(dead_zone=True, coulomb_friction=True, actuator_lag=True, input_delay=True)
    )
    return {"nominal": nominal, "noise_50dB": noisy, "unmodelled": unmod}


def time_optimal_bound(rig: Rig, r: float) -> float:
    """Minimum rest-to-rest time 0 → r [s] of the pendulum with ideal thrust f ∈ [0, f_max]."""
    m = PlantModel(rig)
    f_max = ModelAllocator(rig).f_max

    def arrive(t1: float) -> tuple[float, float]:
        """Full thrust for t1, then zero thrust until θ̇ = 0: (θ at rest, total time)."""
        def acc(f: float) -> Callable[[float, np.ndarray], list[float]]:
            return lambda t, x: [x[1], -m.a_g * math.sin(x[0]) - m.a_c * x[1] + m.b_f * f]

        s1 = solve_ivp(acc(f_max), (0.0, t1), [0.0, 0.0], rtol=1e-10, atol=1e-12)
        x1 = s1.y[:, -1]

        def stop(t: float, x: np.ndarray) -> float:
            return x[1]

        stop.terminal, stop.direction = True, -1
        s2 = solve_ivp(acc(0.0), (0.0, 10.0), x1, events=stop, rtol=1e-10, atol=1e-12)
        return float(s2.y_events[0][0][0]), t1 + float(s2.t_events[0][0])

    t1 = brentq(lambda t: arrive(t)[0] - r, 1e-4, 3.0, xtol=1e-9)
    return arrive(t1)[1]


def run(name: str, rig: Rig, r: float, seed: int = 0, traces: dict | None = None, **options: object) -> dict:
    """One closed-loop step; metrics on the true θ, plus duty statistics (traces stored if given).

    ``options`` go to :func:`aeropend_control.strategies.make_strategy`.
    """
    design_rig = load_rig("thesis_rig")  # the controller knows only the nominal model
    ctl = make_strategy(name, design_rig, **options)
    plant = PlantStepper(rig, seed=seed)
    n = round(HORIZON_S / rig.sample_period)
    theta_true, duty = np.empty(n), np.empty(n)
    sat = 0
    s = plant.sample()
    t0 = time.perf_counter()
    for k in range(n):
        theta_true[k] = plant.x[THETA]
        o = ctl.step(r, Measurement(s["theta"], s["omega_rotor"], s["i_a"]))
        duty[k] = o.duty
        sat += o.saturated != 0
        s = plant.step(o.duty)
    wall = time.perf_counter() - t0
    met = step_metrics(np.arange(n) * rig.sample_period, theta_true, r)
    if traces is not None:
        traces[(name, r)] = (np.arange(n) * rig.sample_period, theta_true, duty)
    return {**met.as_dict(), "table_6_1": met.meets(TABLE_6_1), "goal": met.meets(GOAL),
            "failures_goal": met.failures(GOAL), "saturated_samples": int(sat),
            "duty_max": float(duty.max()), "duty_final": float(duty[-1]),
            "duty_std_last_1s": float(np.std(duty[-round(1.0 / rig.sample_period):])),
            "wall_s": round(wall, 2)}


def plot(scenario: str, traces: dict) -> Path:
    """θ (true) and τ of every run of one scenario → ``bench/results/control_<scenario>.png``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(2, len(BENCH_STRATEGIES), figsize=(4 * len(BENCH_STRATEGIES), 6), sharex=True)
    for j, name in enumerate(BENCH_STRATEGIES):
        for r in SETPOINTS:
            t, th, du = traces[(name, r)]
            axes[0, j].plot(t, th, label=f"θ_ref {r} rad")
            axes[0, j].axhline(r, color="grey", lw=0.5, ls="--")
            axes[1, j].plot(t, du)
        axes[0, j].set_title(f"{name} ({scenario})")
        axes[1, j].set_xlabel("t [s]")
    axes[0, 0].set_ylabel("θ [rad]")
    axes[1, 0].set_ylabel("duty τ")
    axes[0, 0].legend(fontsize=8)
    fig.tight_layout()
    out = OUT.parent / f"control_{scenario}.png"
    fig.savefig(out, dpi=80)
    plt.close(fig)
    return out


def main() -> dict:
    results: dict = {"setup": {"horizon_s": HORIZON_S, "setpoints_rad": SETPOINTS,
                               "python": platform.python_version(), "machine": platform.machine()},
                     "bound_s": {}, "runs": []}
    rigs = scenarios()
    for r in SETPOINTS:
        results["bound_s"][str(r)] = round(time_optimal_bound(rigs["nominal"], r), 4)
    hdr = (f"{'scenario':11s} {'strategy':13s} {'θref':>5s} {'tr':>6s} {'tp':>6s} {'ts':>6s} {'Mp%':>6s} "
           f"{'e_ss':>9s} {'ts/bnd':>6s} T6.1 goal τ_std(last 1 s)")
    print(hdr)
    for scen, rig in rigs.items():
        traces: dict = {}
        for name in BENCH_STRATEGIES:
            for r in SETPOINTS:
                row = {"scenario": scen, "strategy": name, "reference": r, **run(name, rig, r, traces=traces)}
                bound = results["bound_s"][str(r)]
                ts = row["settling_time"]
                row["ts_ratio"] = ts / bound if math.isfinite(ts) else None
                results["runs"].append(row)
                ratio = f"{row['ts_ratio']:6.2f}" if row["ts_ratio"] is not None else "   nan"
                print(f"{scen:11s} {name:13s} {r:5.2f} {row['rise_time']:6.3f} {row['peak_time']:6.3f} "
                      f"{row['settling_time']:6.3f} {row['overshoot']:6.2f} {row['steady_state_error']:9.2e} "
                      f"{ratio} {'ok' if row['table_6_1'] else 'FAIL':4s} {'ok' if row['goal'] else 'no':4s} "
                      f"{row['duty_std_last_1s']:.3f}")
        plot(scen, traces)
    results["estimator_comparison"] = []
    for scen, rig in rigs.items():
        for name in BENCH_STRATEGIES:
            for r in SETPOINTS:
                row = run(name, rig, r, estimator="difference")
                row.update(scenario=scen, strategy=name, reference=r, estimator="difference",
                           ts_ratio=row["settling_time"] / results["bound_s"][str(r)])
                results["estimator_comparison"].append(row)
                print(f"difference estimator {scen:11s} {name:13s} {r:5.2f} ts {row['settling_time']:6.3f} "
                      f"Mp {row['overshoot']:5.2f} τ_std {row['duty_std_last_1s']:.3f}")
    print("time-optimal bound (ideal thrust, rest to rest) [s]:", results["bound_s"])
    OUT.parent.mkdir(parents=True, exist_ok=True)
    OUT.write_text(json.dumps(results, indent=1, default=float) + "\n", encoding="utf-8")
    print(f"wrote {OUT}")
    return results


if __name__ == "__main__":
    main()
