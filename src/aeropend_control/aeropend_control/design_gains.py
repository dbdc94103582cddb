"""``design_gains`` CLI: the position-loop gains a rig file gets, with predicted step metrics.

Designs the FL gains and the scheduled small-signal table exactly as the strategies do
(:meth:`~aeropend_control.strategies.fl_pid.FeedbackLinearizationPID.build`,
:class:`~aeropend_control.strategies.small_signal.SmallSignalPID`), so they are the gains the
controller node runs with, and prints each design's predicted metrics and design model (static or
placed on the drive chain, :mod:`aeropend_control.drive_design`).

Usage::

    design_gains --rig thesis_rig [--omega-n 9] [--zeta 0.7] [--rho 1] [-o gains.yaml]
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from dataclasses import asdict

import numpy as np
import yaml

from aeropend_control.design import REACH_DUTY_MARGIN, LoopDesign, reachable_angle
from aeropend_control.metrics import TABLE_6_1
from aeropend_control.strategies.fl_pid import FeedbackLinearizationPID
from aeropend_control.strategies.small_signal import SmallSignalPID
from aeropend_sim.output_folder import check_output_file
from aeropend_sim.params import load_rig

#: The strategies whose position-loop gains the CLI designs and prints.
DESIGNED = (FeedbackLinearizationPID, SmallSignalPID)


def _row(d: LoopDesign) -> dict[str, float]:
    out = {k: v for k, v in asdict(d).items() if k != "predicted"}
    out["predicted"] = d.predicted.as_dict()
    return out


def main(argv: list[str] | None = None) -> int:
    """CLI ``design_gains``: design the FL and scheduled small-signal gains, print predicted metrics.

    Pole parameters not given take the strategy's default for that rig file
    (:meth:`~aeropend_control.strategies.base.Strategy.default_spec_for`, the robust ζ on a rig
    file that declares its drive), so the gains are those the controller node runs with. Writes a
    YAML gains file with ``-o`` (an existing file only with ``--overwrite``, checked before the
    design). Exit status 2 on a bad argument (one line on stderr).
    """
    ap = argparse.ArgumentParser(prog="design_gains",
                                 description="position-loop gains of a rig file, predicted step metrics")
    ap.add_argument("--rig", default="thesis_rig", help="rig name or YAML path")
    unset = "unset: the strategy's default, as the controller node uses it (default_spec_for)"
    ap.add_argument("--omega-n", type=float, default=None, help=f"closed-loop ω_n [rad/s] ({unset})")
    ap.add_argument("--zeta", type=float, default=None, help=f"damping ratio of the pole pair ({unset})")
    ap.add_argument("--rho", type=float, default=None, help=f"real pole / ω_n ({unset})")
    ap.add_argument("-o", "--output", help="write the gains to this YAML file")
    ap.add_argument("--overwrite", action="store_true", help="replace an existing --output file")
    args = ap.parse_args(argv)
    given = {k: v for k, v in (("omega_n", args.omega_n), ("zeta", args.zeta), ("rho", args.rho))
             if v is not None}
    fl_cls, ss_cls = DESIGNED
    try:
        if args.output:
            check_output_file(args.output, args.overwrite)
        rig = load_rig(args.rig)
        specs = {cls.name: dataclasses.replace(cls.default_spec_for(rig), **given) for cls in DESIGNED}
        for spec in specs.values():
            spec.poles()  # validates
        fl = fl_cls.build(rig, spec=specs[fl_cls.name]).design
        reach = reachable_angle(rig)
        sched = ss_cls.build(rig, spec=specs[ss_cls.name]).table
    except (ValueError, OSError) as exc:
        print(f"design_gains: error: {exc}", file=sys.stderr)
        return 2
    print(f"rig {rig.name}: reach {reach:.4g} rad "
          f"(set points held with {REACH_DUTY_MARGIN:.0%} duty headroom; the schedule stops there)")
    for name, spec in specs.items():
        print(f"{name}: ω_n {spec.omega_n:g} rad/s, ζ {spec.zeta:g}, ρ {spec.rho:g}; poles "
              f"{np.round(spec.poles(), 3).tolist()} rad/s")
    print("strategy          θ0     kp        ki        kd        tr[s]  tp[s]  ts[s]  Mp[%]  Table 6.1  "
          "design model")
    rows = [(fl_cls.name, fl)] + [(ss_cls.name, d) for d in sched]
    for name, d in rows:
        p = d.predicted
        print(f"{name:16s} {d.theta_op:5.2f} {d.kp:9.4g} {d.ki:9.4g} {d.kd:9.4g} {p.rise_time:6.3f} "
              f"{p.peak_time:6.3f} {p.settling_time:6.3f} {p.overshoot:6.2f}  "
              f"{'ok' if p.meets(TABLE_6_1) else 'FAIL':9s}  {d.drive}")
    if args.output:
        doc = {"rig": rig.name, "pole_spec": {k: asdict(v) for k, v in specs.items()}, "reach_rad": reach,
               fl_cls.name: _row(fl),
               ss_cls.name: [_row(d) for d in sched]}
        with open(args.output, "w", encoding="utf-8") as fh:
            yaml.safe_dump(doc, fh, sort_keys=False)
        print(f"wrote {args.output}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
