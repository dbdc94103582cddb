"""``design_gains`` CLI: the controller a rig file gets, checked in closed loop on that rig file.

Designs the FL gains and the scheduled small-signal table exactly as the strategies do
(:meth:`~aeropend_control.strategies.fl_pid.FeedbackLinearizationPID.build`,
:class:`~aeropend_control.strategies.small_signal.SmallSignalPID`), so they are the gains the
controller node runs with, then drives every strategy the rig's family can run through steps from
rest in closed loop on the simulator of the **whole** rig file
(:mod:`aeropend_control.verify.closed_loop`: every switched-on effect, the actuator's dead time and
lag, the rotor's response, the sensor's quantum, noise and sample rate, the command's saturation).
Every step figure it prints comes from those runs, not from the linear design model. When the
default pole pattern misses the goal (ts ≤ 1 s, M_p ≤ 5 %), slower and more damped patterns are
tried in closed loop and the fastest that meets it is recommended; when none does, the command says
so, with the attainable figures and what limits them.

Usage::

    design_gains --rig fitted.yaml [--steps 0.2,0.4,0.6] [--omega-n 9] [--zeta 0.7] [--rho 1] [-o gains.yaml]
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import sys
from collections.abc import Callable
from dataclasses import asdict
from typing import TYPE_CHECKING, Any

import numpy as np
import yaml

from aeropend_control.design import REACH_DUTY_MARGIN, LoopDesign, PoleSpec, reachable_angle
from aeropend_control.strategies.fl_pid import FeedbackLinearizationPID
from aeropend_control.strategies.registry import strategy_class, strategy_names
from aeropend_control.strategies.small_signal import SmallSignalPID
from aeropend_sim.output_folder import (
    check_output_file,
    exits_cleanly_on_faults,
    is_fault,
    write_file_atomically,
)
from aeropend_sim.params import Rig, load_rig

if TYPE_CHECKING:
    from concurrent.futures import ProcessPoolExecutor

#: The strategies whose position-loop gains the CLI designs, prints and tunes (θ only).
DESIGNED = (FeedbackLinearizationPID, SmallSignalPID)


def _row(d: LoopDesign) -> dict[str, float]:
    out = {k: v for k, v in asdict(d).items() if k != "predicted"}
    out["linear_prediction"] = d.predicted.as_dict()
    return out


def _steps(text: str) -> tuple[float, ...]:
    try:
        vals = tuple(float(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"steps {text!r}: expected comma-separated angles in rad, "
                                         "e.g. 0.2,0.4,0.6") from None
    if not vals or not all(math.isfinite(v) and v > 0.0 for v in vals):
        raise argparse.ArgumentTypeError(f"steps {text!r}: every angle must be finite and > 0 rad")
    return vals


def limits_of(rig: Rig) -> str:
    """What slows the drive of ``rig`` down, in words (dead time, lag, the rotor's slowest mode)."""
    from aeropend_control.drive_design import rotor_rate
    from aeropend_sim.model import plant_model
    m = plant_model(rig)
    parts = []
    if m.delay > 0.0:
        parts.append(f"dead time {m.delay:.3g} s")
    if m.lag and m.T_a > 0.0:
        parts.append(f"actuator lag {m.T_a:.3g} s")
    try:
        rate = rotor_rate(rig)
        if math.isfinite(rate):
            parts.append(f"rotor response {1.0 / rate:.3g} s")
    except ValueError:
        pass
    if rig.effects.quantisation and rig.sensors.theta_quantum > 0.0:
        parts.append(f"angle quantum {rig.sensors.theta_quantum:.3g} rad")
    parts.append(f"sample period {rig.sample_period:.3g} s")
    return ", ".join(parts)


def _fmt(v: float, width: int = 6, digits: int = 3) -> str:
    return f"{v:{width}.{digits}f}" if math.isfinite(v) else f"{'—':>{width}s}"


def _print_verdict(label: str, v) -> None:
    for r in v.runs:
        m = r.metrics
        ts, mp, tr = (m.settling_time, m.overshoot, m.rise_time) if m is not None else (math.nan,) * 3
        fails = r.failures()
        print(f"  {label:24s} {r.reference:5.3f} {_fmt(tr)} {_fmt(ts)} {_fmt(mp, 7, 2)}  "
              f"{'goal met' if not fails else '; '.join(fails)}")
    if not v.complete:
        print(f"  {label:24s} (stopped after the first failing step)")


def _progress(text: str) -> None:
    print(f"design_gains: checking {text} ...", file=sys.stderr, flush=True)


def _check_one(rig: Rig, name: str, spec: PoleSpec | None, steps: tuple[float, ...], tune: bool) -> tuple:
    """One strategy's closed-loop check (run in a worker process by :func:`check`): ``("tuned",
    (first, best))`` for a pattern to tune or verify, ``("others", verdict or refusal text)``."""
    from aeropend_control.verify.closed_loop import tune as tune_fn
    from aeropend_control.verify.closed_loop import verify

    try:
        pattern = spec or strategy_class(name).default_spec_for(rig)
        _progress(f"{name}: ω_n {pattern.omega_n:.3g} rad/s, ζ {pattern.zeta:g}")
        if spec is not None and tune:
            return "tuned", tune_fn(rig, name, pattern, steps, _progress)
        if spec is not None:
            v = verify(rig, name, pattern, steps)
            return "tuned", (v, v)
        return "others", verify(rig, name, pattern, steps)
    except ValueError as exc:  # ControllerConfigError, DesignError: refused with the reason
        return "others", str(exc)


#: Worker processes of a design's closed loops (:func:`check`'s strategies, a closed-loop
#: excitation design's sequences: :func:`design_workers`); 1 = in this process.
WORKERS_ENV = "AEROPEND_DESIGN_WORKERS"


def design_workers(jobs: int) -> int:
    """Worker processes for ``jobs`` independent closed loops: ``AEROPEND_DESIGN_WORKERS`` when set
    (1 runs them in this process), else one per job up to the machine's cores."""
    import os

    return int(os.environ.get(WORKERS_ENV, "0")) or max(1, min(int(jobs), os.cpu_count() or 1))


def design_pool(workers: int, initializer: Callable[..., None] | None = None, initargs: tuple[Any, ...] = ()
                ) -> ProcessPoolExecutor:
    """A pool of ``workers`` processes for a design's closed loops (a
    :class:`concurrent.futures.ProcessPoolExecutor`, spawned: no thread or OpenMP runtime of this
    process is forked). Each worker first starts a thread that ends it when this process is gone
    (:func:`_end_with_parent`): a design killed with SIGKILL or SIGTERM, which runs no clean-up,
    left its idle workers behind for good (240 MB each); then it runs ``initializer(*initargs)``."""
    import os
    from concurrent.futures import ProcessPoolExecutor
    from multiprocessing import get_context

    return ProcessPoolExecutor(workers, mp_context=get_context("spawn"), initializer=_start_worker,
                               initargs=(os.getpid(), initializer, initargs))


def _start_worker(parent: int, initializer: Callable[..., None] | None, initargs: tuple[Any, ...]) -> None:
    _end_with_parent(parent)
    if initializer is not None:
        initializer(*initargs)


#: How often a design worker checks that the process that started it is still there [s].
PARENT_CHECK_S = 0.5


def _end_with_parent(parent: int) -> None:
    """Start a daemon thread that ends this process (exit status 1) once its parent ``parent`` is
    gone (it is then another process's child: ``os.getppid()`` changes)."""
    import os
    import threading
    import time

    def watch() -> None:
        while os.getppid() == parent:
            time.sleep(PARENT_CHECK_S)
        os._exit(1)

    threading.Thread(target=watch, name="design-worker-parent-watch", daemon=True).start()


def check(rig: Rig, specs: dict[str, PoleSpec], steps: tuple[float, ...], tune_specs: bool = True) -> dict:
    """Closed-loop verdicts of every strategy on ``rig``: θ-only strategies tuned
    (:func:`~aeropend_control.verify.closed_loop.tune`), the others at their default pattern or
    refused with the reason. Progress on stderr as it goes.

    The strategies are checked in parallel, one worker process each, up to the machine's cores
    (``AEROPEND_DESIGN_WORKERS`` sets the number; 1 runs them here, one after the other); the
    verdicts do not depend on it (each closed loop is deterministic)."""
    names = [n for n in strategy_names() if not strategy_class(n).required]  # required: a setting of its own
    jobs = [(rig, n, specs.get(n), steps, tune_specs) for n in names]
    workers = design_workers(len(jobs))
    if workers > 1:
        with design_pool(workers) as pool:
            results = list(pool.map(_check_one, *zip(*jobs, strict=True)))
    else:
        results = [_check_one(*job) for job in jobs]
    out: dict = {"tuned": {}, "others": {}}
    for name, (kind, value) in zip(names, results, strict=True):
        out[kind][name] = value
    return out


def _report(rig: Rig, result: dict, rig_arg: str) -> dict:
    """Print the closed-loop table and the recommendation; return it for the YAML file."""
    limits = limits_of(rig)
    print(f"closed loop on the whole rig file ({limits}), steps from rest; goal ts ≤ 1 s (2 % band), "
          "M_p ≤ 5 %:")
    print(f"  {'strategy, ω_n, ζ':24s} {'θ_ref':>5s} {'tr[s]':>6s} {'ts[s]':>6s} {'Mp[%]':>7s}  verdict")
    for name, (first, best) in result["tuned"].items():
        _print_verdict(f"{name} {first.spec.omega_n:.3g} {first.spec.zeta:g}", first)
        if best is not first:
            _print_verdict(f"{name} {best.spec.omega_n:.3g} {best.spec.zeta:g} tuned", best)
    for name, v in result["others"].items():
        if isinstance(v, str):
            print(f"  {name}: refused: {v}")
        else:
            _print_verdict(f"{name} {v.spec.omega_n:.3g} {v.spec.zeta:g}", v)
            print(f"  {name}: needs the measured rotor speed ω₁ and armature current i_a on the rig")
    cands = [best for _, best in result["tuned"].values()]
    if not cands:
        print("no strategy runs on this rig")
        return {"recommended": None}
    meeting = [v for v in cands if v.meets]
    pick = min(meeting or cands, key=lambda v: v.cost())
    ts, mp = pick.worst("settling_time"), pick.worst("overshoot")
    if meeting:
        print(f"recommended: {pick.strategy} with ω_n {pick.spec.omega_n:.4g} rad/s, ζ {pick.spec.zeta:g}: "
              f"worst step ts {ts:.3g} s, M_p {mp:.3g} % (goal met)")
    elif pick.settles:
        print(f"goal not attainable on this rig ({limits}): the fastest pattern with M_p ≤ 5 % "
              f"settles in {ts:.3g} s (M_p {mp:.3g} %): {pick.strategy} with ω_n "
              f"{pick.spec.omega_n:.4g} rad/s, ζ {pick.spec.zeta:g}")
    elif pick.ends_in_band:
        print(f"goal not attainable on this rig ({limits}): no pattern tried settles with M_p ≤ 5 %; the "
              f"fastest whose every step ends in the 2 % band settles in {ts:.3g} s with M_p {mp:.3g} %: "
              f"{pick.strategy} with ω_n {pick.spec.omega_n:.4g} rad/s, ζ {pick.spec.zeta:g}")
    else:
        why = "; ".join(f for r in pick.runs for f in r.failures())
        print(f"goal not attainable on this rig ({limits}): no pattern tried settles with M_p ≤ 5 %; "
              f"least bad: {pick.strategy} with ω_n {pick.spec.omega_n:.4g} rad/s, ζ {pick.spec.zeta:g} "
              f"({why})")
    cmd = (f"controller --ros-args -p rig:={rig_arg} -p strategy:={pick.strategy} "
           f"-p omega_n:={pick.spec.omega_n:.6g} -p zeta:={pick.spec.zeta:.6g} -p rho:={pick.spec.rho:.6g}")
    print(f"run it: {cmd}")
    return {"recommended": {"strategy": pick.strategy, "pole_spec": asdict(pick.spec),
                            "goal_met": bool(pick.meets),
                            "worst_settling_time_s": ts, "worst_overshoot_pct": mp, "command": cmd}}


def _verdict_doc(v) -> dict:
    return {"pole_spec": asdict(v.spec), "goal_met": bool(v.meets),
            "steps": [{"reference_rad": r.reference, "status": r.status, "detail": r.detail,
                       "metrics": r.metrics.as_dict() if r.metrics is not None else None} for r in v.runs]}


@exits_cleanly_on_faults("design_gains")
def main(argv: list[str] | None = None) -> int:
    """CLI ``design_gains``: design the gains, check every strategy in closed loop on the rig file.

    Pole parameters not given take the strategy's default for that rig file
    (:meth:`~aeropend_control.strategies.base.Strategy.default_spec_for`), so the gains are those the
    controller node runs with; the recommendation names the pattern to pass to the node. Writes a
    YAML file with ``-o`` (an existing file only with ``--overwrite``, checked before the design).
    Exit status 2 on a bad argument or a rig that cannot be controlled (one line on stderr).
    """
    ap = argparse.ArgumentParser(
        prog="design_gains",
        description="position-loop gains of a rig file, checked in closed loop on the whole rig file "
                    "(steps from rest; goal ts ≤ 1 s, M_p ≤ 5 %), and the strategy and pole pattern to run")
    ap.add_argument("--rig", default="thesis_rig", help="rig name or YAML path")
    unset = "unset: the strategy's default, as the controller node uses it (default_spec_for)"
    ap.add_argument("--omega-n", type=float, default=None, help=f"closed-loop ω_n [rad/s] ({unset})")
    ap.add_argument("--zeta", type=float, default=None, help=f"damping ratio of the pole pair ({unset})")
    ap.add_argument("--rho", type=float, default=None, help=f"real pole / ω_n ({unset})")
    ap.add_argument("--steps", type=_steps, default=(0.2, 0.4, 0.6),
                    help="step references [rad] of the closed-loop check, comma-separated "
                         "(default 0.2,0.4,0.6; cut to the rig's reach)")
    ap.add_argument("--no-tune", action="store_true",
                    help="check the given (or default) pole pattern only; do not search slower patterns")
    ap.add_argument("-o", "--output", help="write the gains and the closed-loop figures to this YAML file")
    ap.add_argument("--overwrite", action="store_true", help="replace an existing --output file")
    args = ap.parse_args(argv)
    given = {k: v for k, v in (("omega_n", args.omega_n), ("zeta", args.zeta), ("rho", args.rho))
             if v is not None}
    fl_cls, ss_cls = DESIGNED
    try:
        if args.output:
            check_output_file(args.output, args.overwrite)
        rig = load_rig(args.rig)
        reach = reachable_angle(rig)
        specs = {cls.name: dataclasses.replace(cls.default_spec_for(rig), **given) for cls in DESIGNED}
        for spec in specs.values():
            spec.poles()  # validates
        fl = fl_cls.build(rig, spec=specs[fl_cls.name]).design
        sched = ss_cls.build(rig, spec=specs[ss_cls.name]).table
    except (ValueError, OSError) as exc:
        if is_fault(exc):
            raise
        print(f"design_gains: error: {exc}", file=sys.stderr)
        return 2
    print(f"rig {rig.name} ({rig.family}): reach {reach:.4g} rad "
          f"(set points held with {REACH_DUTY_MARGIN:.0%} duty headroom; the schedule stops there)")
    for name, spec in specs.items():
        print(f"{name}: ω_n {spec.omega_n:g} rad/s, ζ {spec.zeta:g}, ρ {spec.rho:g}; poles "
              f"{np.round(spec.poles(), 3).tolist()} rad/s")
    print("strategy          θ0     kp        ki        kd        design model")
    rows = [(fl_cls.name, fl)] + [(ss_cls.name, d) for d in sched]
    for name, d in rows:
        print(f"{name:16s} {d.theta_op:5.2f} {d.kp:9.4g} {d.ki:9.4g} {d.kd:9.4g}  {d.drive}")
    result = check(rig, specs, args.steps, tune_specs=not args.no_tune and not given)
    rec = _report(rig, result, args.rig)
    if args.output:
        doc = {"rig": rig.name, "pole_spec": {k: asdict(v) for k, v in specs.items()}, "reach_rad": reach,
               fl_cls.name: _row(fl),
               ss_cls.name: [_row(d) for d in sched],
               "closed_loop": {name: {"default": _verdict_doc(first), "chosen": _verdict_doc(best)}
                               for name, (first, best) in result["tuned"].items()},
               "others": {name: (v if isinstance(v, str) else _verdict_doc(v))
                          for name, v in result["others"].items()},
               **rec}
        write_file_atomically(args.output, yaml.safe_dump(doc, sort_keys=False, allow_unicode=True))
        print(f"wrote {args.output}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
