"""Benchmark: the predicted step of a designed loop, python-control's loop against the doubling.

``aeropend_control.design.predict_step`` samples a linear loop's unit step (5 s at 1 ms, 5 001
samples, or 0.5 s at 0.1 ms for a current loop) for its rise, settling time and M_p.
``design_gains`` and every controller's drive-chain search call it hundreds of times per rig.
This times four loops: two the designs make for the thesis rig (the feedback-linearised I-PD on
1/s², the small-signal I-PD at 0.4 rad with the linearised drive chain the drive-chain search puts
under it), a stiff third-order loop sampled at 0.1 ms (as the current loop's prediction is) and a
lightly damped loop with a feedthrough. For each: python-control's
:func:`control.step_response` (a Python loop over the samples) and
:func:`aeropend_control.design.step_samples` (the exact discretisation of a constant input by
doubling), the largest difference of their samples relative to the response's peak, and whether
the step metrics agree (the rise, peak and settling times to the sample, M_p and the steady-state
error to 1e-9). It writes ``bench/results/step_response.json``.

Run: ``.venv/bin/python -m bench.bench_step_response``
"""

from __future__ import annotations

import json
import os
import platform
import time
from pathlib import Path

import numpy as np

OUT = Path(__file__).resolve().parent / "results" / "step_response.json"
REPEATS = 20


def _loops() -> dict[str, tuple[object, float, float]]:
    """name -> (loop r → θ, horizon [s], dt [s]) as the designs build them for the thesis rig."""
    import control

    from aeropend_control.design import PoleSpec, _closed_loop_2nd, design_small_signal, place_ipd
    from aeropend_control.drive_design import DriveSpec, closed_loop, drive_model
    from aeropend_sim.params import load_rig

    rig = load_rig("thesis_rig")
    kp, ki, kd = place_ipd(0.0, 0.0, 1.0, PoleSpec())
    d = design_small_signal(rig, 0.4, PoleSpec())
    drive = drive_model(rig, 0.4, DriveSpec("duty"))
    return {
        "fl_ipd_1_over_s2": (_closed_loop_2nd(0.0, 0.0, 1.0, kp, ki, kd), 5.0, 1e-3),
        "small_signal_0.4rad_with_its_drive": (
            closed_loop(d.a0, d.a1, d.g, drive, (d.kp, d.ki, d.kd), False), 5.0, 1e-3),
        "stiff_3rd_order_0.1ms": (control.tf([5e4], [1.0, 300.0, 2.2e4, 5e4]), 0.5, 1e-4),
        "lightly_damped_with_feedthrough": (
            control.ss([[0.0, 1.0], [-400.0, -0.8]], [[0.0], [400.0]], [[1.0, 0.0]], [[0.25]]), 3.0, 1e-3),
    }


def _best_ms(fn, repeats: int = REPEATS) -> float:
    best = float("inf")
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best * 1e3


def main() -> None:
    import control

    from aeropend_control.design import step_samples
    from aeropend_control.metrics import step_metrics

    rows = {}
    for name, (sys, horizon, dt) in _loops().items():
        t = np.arange(0.0, horizon + dt / 2, dt)
        _, want = control.step_response(sys, t)
        want = np.asarray(want).ravel()
        got = step_samples(sys, t.size, dt)
        a, b = step_metrics(t, want, 1.0), step_metrics(t, got, 1.0)
        same_times = all(np.isclose(getattr(a, k), getattr(b, k), rtol=0.0, atol=dt / 10, equal_nan=True)
                         for k in ("rise_time", "peak_time", "settling_time"))
        same_values = all(np.isclose(getattr(a, k), getattr(b, k), rtol=0.0, atol=1e-9, equal_nan=True)
                          for k in ("overshoot", "steady_state_error"))
        rows[name] = {
            "samples": int(t.size),
            "python_control_ms": _best_ms(lambda s=sys, t=t: control.step_response(s, t)),
            "step_samples_ms": _best_ms(lambda s=sys, n=t.size, h=dt: step_samples(s, n, h)),
            "max_rel_difference": float(np.max(np.abs(got - want)) / np.max(np.abs(want))),
            "metrics_equal": bool(same_times and same_values),
        }
        rows[name]["speedup"] = rows[name]["python_control_ms"] / rows[name]["step_samples_ms"]
        r = rows[name]
        print(f"{name:34s} {r['python_control_ms']:8.2f} ms -> {r['step_samples_ms']:6.3f} ms "
              f"(×{r['speedup']:.0f}), max rel diff {r['max_rel_difference']:.1e}, "
              f"metrics equal {r['metrics_equal']}")
    doc = {"what": f"best of {REPEATS} wall times per call, one process",
           "load_average_1min": os.getloadavg()[0],
           "python": platform.python_version(), "control": control.__version__,
           "date": time.strftime("%Y-%m-%d"), "loops": rows,
           "summary": {"speedup_min": min(r["speedup"] for r in rows.values()),
                       "max_rel_difference": max(r["max_rel_difference"] for r in rows.values()),
                       "metrics_equal_all": all(r["metrics_equal"] for r in rows.values())}}
    OUT.write_text(json.dumps(doc, indent=2) + "\n", encoding="utf-8")
    print(f"wrote {OUT}")


if __name__ == "__main__":
    main()
