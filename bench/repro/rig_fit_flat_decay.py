"""Reproducer (2026-12-01, fixed the same day by ``rig_search.open_profile``): ``rig fit`` reported a
rod damping as determined from a free decay in which the rod hardly moves, at a value the rig does
not have.

Found through ``bench_design_parameters``: its one design whose angle limits failed on the rig
(dc_hbridge_0, first log = balance table + free decay) said the limits were assured, and the rig's
recorded angle went 0.020 rad below the stated range. The design trusted the first fit's
``pendulum.c_over_J = 14.863 ± 2.2 1/s`` (15 %); the drawn rig's c/J is 10.10 (47 % off, 2.2σ).

The free decay (``decay.csv``, 14 s logged once the propeller has stopped) holds almost nothing: the
rod is heavily damped (ζ ≈ 0.45), so the log shows it creep from −4 to +1 encoder quanta in 0.3 s
and then 0 for the rest. ``rig fit`` refused mgd/J and L/J (the table fixes only their ratio) and
left mgd/J at its best value, 0.082 1/s² (the rig: 127), where the model has no restoring force:
with the initial angle and velocity free (the decay block's nuisance parameters) a damped creep
θ₀ + θ̇₀/c·(1 − e^(−c·t)) reproduces the −4 → 0 quanta, and c/J was fitted as its time constant.
With mgd/J and L/J stated at the rig's values the same inputs fit c/J = 9.76 ± 0.8 1/s. The free
run from the measured start (``rig check``, and ``rig fit``'s own summary) gave NRMSE 0.47 on the
decay for the fitted rig and 0.015 for the same file with the drawn rig's mgd/J, L/J and c/J.

In the fit's own terms the creep was not the better fit: at the rod's mgd/J and L/J the joint cost
½‖r‖² is 8.2 against the creep's 28.8. The joint fit had stopped in the creep's valley; the
refusals then said only that the inputs do not fix mgd/J *there*. The fix
(:func:`aeropend_ident.greybox.rig_search.open_profile`, stage 7 of docs/rig_command.md) profiles
the fit along what its refused parameters leave open: the refused parameter that weighs most in each
open direction held at points out to its search bound, everything else solved again; a lower probe is
a better valley and the fit is solved again from it (a probe as good shows a fitted parameter that
holds only given the refused ones, refused then too). Here it finds the rod's valley, and the fit
gives mgd/J 128.0 ± 14.3, L/J 497.7 ± 55 and c/J 9.77 ± 0.85 (the rig: 126.9, 493.2, 10.10).

This script draws the rig, writes its lab logs, runs ``rig new`` and ``rig fit`` on the balance
table and the decay, and prints the fitted c/J against the drawn one, the free-run NRMSE of the
fitted rig and of the rig's own values, and c/J fitted again with mgd/J and L/J stated at the rig's
values. Before the fix: c/J = 14.863 ± 2.2, NRMSE 0.4696 against 0.0146; with it, c/J = 9.77 ±
0.85 and the two NRMSEs alike. About 20 s.

Usage: ``python -m bench.repro.rig_fit_flat_decay``
"""

from __future__ import annotations

import contextlib
import io
import re
import tempfile
from pathlib import Path

import numpy as np

from bench.fixtures import family_lab as fl

#: The bench's draw (bench_design_parameters: seed 63000, the first dc_hbridge rig).
SEED = 63000
KEYS = ("mgd_over_J", "L_over_J", "c_over_J")


def _run(fn, argv: list[str]) -> str:
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf), contextlib.redirect_stderr(buf):
        try:
            fn(argv)
        except SystemExit:
            pass
    return buf.getvalue()


def _with_truth(path: Path, truth: dict[str, float], out: Path) -> Path:
    """The fitted rig file with the drawn rig's mgd/J, L/J and c/J."""
    text = path.read_text(encoding="utf-8")
    for k in KEYS:
        text = re.sub(rf"^(  {k}: {{value: )[^,]*", rf"\g<1>{truth[k]!r}", text, flags=re.M)
    out.write_text(text, encoding="utf-8")
    return out


def _stated(path: Path, truth: dict[str, float], out: Path) -> Path:
    """``rig new``'s file with mgd/J and L/J stated at the drawn rig's values (c/J left to be fitted)."""
    text = path.read_text(encoding="utf-8")
    for k in ("mgd_over_J", "L_over_J"):
        pattern = rf'^(  {k}: {{value: )[^,]*(, unit: "[^"]*", source: )"[^"]*"'
        text = re.sub(pattern, rf'\g<1>{truth[k]!r}\g<2>"stated by the lab (rig new --stated)"', text,
                      flags=re.M)
    out.write_text(text, encoding="utf-8")
    return out


def main() -> None:
    from aeropend_ident.cli.rig import main as rig

    lab = fl.draw_rigs("dc_hbridge", 1, seed=SEED)[0]
    truth = {k: float(lab.truth[k]) for k in KEYS}
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp)
        inputs = fl.lab_logs(lab, d / "logs")
        logs = [i for i in inputs if "balance.csv" in i or "decay.csv" in i]
        decay = next(i for i in logs if "decay.csv" in i)
        theta = np.loadtxt(decay.partition(":")[0], delimiter=",", skiprows=1)[:, 2]
        _run(rig, ["new", "--actuator", "dc_hbridge", "--stated", *fl.stated(lab), "-o", str(d / "new.yaml")])
        text = _run(rig, ["fit", str(d / "new.yaml"), *logs, "-o", str(d / "first.yaml")])
        fitted = re.search(r"fitted\s+pendulum\.c_over_J = (\S+) ± (\S+)", text)
        given = _run(rig, ["fit", str(_stated(d / "new.yaml", truth, d / "given.yaml")), *logs, "-o",
                           str(d / "given_fit.yaml")])
        cond = re.search(r"fitted\s+pendulum\.c_over_J = (\S+) ± (\S+)", given)
        nrmse = {}
        drawn = _with_truth(d / "first.yaml", truth, d / "truth.yaml")
        for label, path in (("fitted", d / "first.yaml"), ("drawn mgd/J, L/J, c/J", drawn)):
            out = _run(rig, ["check", str(path), decay])
            m = re.search(r"free-run θ on decay\.csv \(free decay\): NRMSE (\S+)", out)
            nrmse[label] = m.group(1) if m else "?"
    print(f"{lab.name}: decay log θ from {theta.min():.4f} to {theta.max():.4f} rad")
    print("rig fit: " + (f"c/J = {fitted.group(1)} ± {fitted.group(2)} 1/s (fitted)" if fitted else
                         "c/J not reported as fitted"))
    print(f"drawn rig: c/J = {truth['c_over_J']:.4g} 1/s, mgd/J = {truth['mgd_over_J']:.4g} 1/s², "
          f"L/J = {truth['L_over_J']:.4g} 1/(kg·m)")
    print("free-run NRMSE on the decay (rig check): " + ", ".join(f"{k} {v}" for k, v in nrmse.items()))
    print("rig fit with mgd/J and L/J stated at the rig's values: " +
          (f"c/J = {cond.group(1)} ± {cond.group(2)} 1/s" if cond else "c/J not reported as fitted"))


if __name__ == "__main__":
    main()
