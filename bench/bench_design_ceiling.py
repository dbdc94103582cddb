"""What more data of any kind buys the unfinished triples (issue 63: the ceiling of one recording).

:mod:`bench.bench_design_discrimination` measures one designed recording on the lab benchmark's
triples whose three effects ``gap`` did not all name. This benchmark asks how far *generic* data
takes the same diagnoses: each case (rebuilt from its seed) is diagnosed by ``gap`` as the lab
benchmark runs it (:func:`bench.bench_gap_lab.lab_gap`: fit session 1, held-out session 2, three
effects at most) with 0, 1 and 3 extra fit recordings of :data:`DURATION` s each: seeded APRBS
sequences (seeds :data:`SEEDS`) inside the design's default limits, recorded on the case's
independent truth plant as a designed recording is
(:func:`bench.bench_design_discrimination.designed_recording`: its noise, quantum, logging rate,
jitter and dropped rows, open loop from rest).

Scored as the lab benchmark scores: all truth effects named (chosen, or in a chosen effect's
``ambiguous_with``).

Usage: ``python -m bench.bench_design_ceiling [--only 73,80] [--workers 2] [-q]`` ->
``bench/results/design_ceiling.{json,md}``.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path
from typing import Any

from bench.bench_design_discrimination import DEFAULT_CASES, DURATION

RESULTS = Path(__file__).resolve().parent / "results"
#: Seeds of the extra APRBS recordings (the design's own seed 0 is not reused).
SEEDS = (11, 12, 13)
#: Extra recordings given to ``gap`` beside the fit session.
EXTRAS = (0, 1, 3)


def run_case(job: dict[str, Any]) -> dict[str, Any]:
    """One case (module doc): ``gap`` with 0, 1 and 3 extra APRBS recordings."""
    from aeropend_ident.design.sequence import AprbsShape, Limits, aprbs_vector, sequence
    from bench import bench_gap_lab as lab
    from bench.bench_design_discrimination import _named, designed_recording
    from bench.fixtures.truth_plant import OUT_OF_CATALOG

    spec = lab.case_list()[job["index"]]
    case = lab.build_case(spec)
    fit, held = lab.prepared(case, spec)
    limits = Limits.from_recordings([fit[0].channels["theta"]], [fit[0].duty], fit[0].dt,
                                    quantum=case["quantum"])
    shape = AprbsShape.for_duration(DURATION)
    extra = [designed_recording(case, spec, sequence(aprbs_vector(shape, s), shape, limits))[0]
             for s in SEEDS]
    row: dict[str, Any] = {"index": spec["index"], "kind": spec["kind"], "mode": spec["mode"],
                           "rate_hz": spec["rate_hz"], "channels": spec["channels"],
                           "truth": sorted(t for t in case["effects"] if t not in OUT_OF_CATALOG)}
    for n in EXTRAS:
        t0 = time.perf_counter()
        res = lab.lab_gap(case, [*fit, *extra[:n]], held)
        row[f"extra_{n}"] = {**_named(spec, case, res), "s": time.perf_counter() - t0}
    return row


def write_md(path: Path, doc: dict[str, Any]) -> None:
    m, rows = doc["meta"], doc["cases"]
    named = {n: sum(r[f"extra_{n}"]["pass"] for r in rows) for n in EXTRAS}
    lines = [
        "# More generic data on the unfinished triples (issue 63: the ceiling of one recording)",
        "",
        f"`python -m bench.bench_design_ceiling` at {m['commit']}, {m['wall_s']:.0f} s wall on "
        f"{m['workers']} worker(s); extra recordings: APRBS of {DURATION:g} s each on the truth plant. What "
        "it does: its module docstring.",
        "",
        "- all truth effects named: " + ", ".join(
            f"**{named[n]}/{len(rows)}** with {n} extra recording(s) ({n * DURATION:g} s)" for n in EXTRAS),
        "",
        "| case | mode | Hz | channels | truth | " + " | ".join(f"chosen, {n} extra" for n in EXTRAS) + " |",
        "|---|---|---|---|---|" + "---|" * len(EXTRAS),
    ]
    for r in rows:
        runs = [r[f"extra_{n}"] for n in EXTRAS]
        cells = [f"{', '.join(x['chosen']) or '—'} ({'yes' if x['pass'] else 'no'})" for x in runs]
        lines.append(f"| {r['index']} | {r['mode']} | {r['rate_hz']} | {r['channels']} | "
                     f"{', '.join(r['truth'])} | " + " | ".join(cells) + " |")
    lines.append("")
    path.write_text("\n".join(lines))


def summarise(rows: list[dict[str, Any]]) -> dict[str, Any]:
    return {**{f"all_named_extra_{n}": sum(r[f"extra_{n}"]["pass"] for r in rows) for n in EXTRAS},
            "cases": len(rows)}


def main(argv: list[str] | None = None) -> int:
    from bench.bench_design_discrimination import lab_case_bench

    return lab_case_bench(__doc__.split("\n", 1)[0], run_case, summarise, write_md,
                          default=[i for i in DEFAULT_CASES if i not in (0, 2)],
                          out=RESULTS / "design_ceiling", desc="ceiling",
                          meta={"duration_s": DURATION, "seeds": list(SEEDS)}, argv=argv)


if __name__ == "__main__":
    sys.exit(main())
