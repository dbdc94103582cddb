"""rig fit and rig check (``aeropend_ident.greybox.rig_fit``, ``rig_check``): a rig whose free run
diverges on a recording is reported as divergence, never with an NRMSE (issue 36 item 4; the one
rule of :func:`aeropend_ident.io.overlay_axes.diverges`).

Before the fix ``rig fit`` printed ``aeropendulum.csv: 22.954`` for matheusbucater's sawtooth fitted
alone (θ → 93 rad: the rod spun over the top) and ``rig check`` did the same.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from aeropend_ident.cli.rig import main
from aeropend_ident.greybox.rig_check import check_rig
from aeropend_ident.greybox.rig_fit import fit_rig

# an ESC rig whose thrust is ~100× too strong: any command above idle spins the rod over the top
STRONG = ["pendulum.mass=120g", "pendulum.com_distance=18cm", "pendulum.thrust_arm=0.15m",
          "motor.gear_ratio=1", "actuator.omega_max=1085rad/s", "thrust.K_q=1e-4",
          "actuator.idle_duty=0.05", "actuator.curve_exponent=1", "motor.T_m=50ms",
          "actuator.input_delay=20ms", "pendulum.inertia=0.006"]


def _log(tmp_path: Path) -> str:
    """A 10 s step log at 100 Hz: the rod settles at 0.2 and 0.4 rad (a gentle second-order response)."""
    t = np.arange(1000) * 0.01
    duty = np.where(t < 5.0, 0.3, 0.5)
    target = np.where(t < 5.0, 0.2, 0.4)
    theta = np.empty_like(t)
    th, om = 0.0, 0.0
    for k in range(t.size):  # θ'' = 16 (target − θ) − 4 θ'
        theta[k] = th
        om += 0.01 * (16.0 * (target[k] - th) - 4.0 * om)
        th += 0.01 * om
    path = tmp_path / "steps.csv"
    np.savetxt(path, np.column_stack([t, duty, theta]), delimiter=",", header="time_s,duty,theta_rad",
               comments="")
    preset = tmp_path / "log.yaml"
    preset.write_text("angle_col: theta_rad\ntime_col: time_s\ninput_col: duty\ninput_kind: duty\n",
                      encoding="utf-8")
    return f"{path}:{preset}"


def test_rig_check_reports_a_diverging_free_run_as_divergence(tmp_path: Path) -> None:
    rig = tmp_path / "strong.yaml"
    assert main(["new", "--actuator", "esc", "--stated", *STRONG, "-o", str(rig)]) == 0
    text = check_rig(rig, [_log(tmp_path)])
    line = next(ln for ln in text.splitlines() if "steps.csv" in ln and "free-run" in ln)
    assert "DIVERGES: diverges at t = " in line and "NRMSE" not in line


def test_rig_fit_reports_a_diverging_free_run_as_divergence(tmp_path: Path) -> None:
    rig = tmp_path / "strong.yaml"
    assert main(["new", "--actuator", "esc", "--stated", *STRONG, "-o", str(rig)]) == 0  # c/J left to fit
    res = fit_rig(rig, [_log(tmp_path)])
    assert res.nrmse["steps.csv"] is None and res.divergence["steps.csv"].startswith("diverges at t = ")
    assert "  free-run θ on steps.csv: DIVERGES: diverges at t = " in res.summary()
