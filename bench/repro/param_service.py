"""Reproducer: a ``get_parameters`` request unanswered after ``wait_for_service`` (issue 15).

``test_params_files_ros[bridge.yaml]`` failed once (fresh clone of bf4e45a): the bridge's
``get_parameters`` service was available (``wait_for_service`` returned True) but the request got
no response in 20 s. Suspected: rmw_fastrtps' service server drops a response when the client's
response reader is not matched yet (ros2/rmw_fastrtps#390/#467). This script repeats exactly what
the test does — start the node as a process with its shipped parameters file, a client on a
private context, ``wait_for_service``, one request — ``--runs`` times, each on its own claimed
domain, optionally under ``--hogs`` CPU-bound processes, and counts per run: service available,
answered, time to the answer, and, when unanswered, whether a second request on the same client
is answered (a lost response vs a server that does not serve at all).

Usage: ``python -m bench.repro.param_service [--runs 200] [--hogs 1] [--node bridge]``;
writes ``bench/results/repro_param_service.json``.
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from aeropend_sim.ros.domain import claim_domain
from aeropend_sim.ros.harness import isolated_env, node_command, private_node, reap, stop, wait_for_server
from bench.bench_data_plane import HOG

ROOT = Path(__file__).resolve().parents[2]

NODES = {
    "bridge": ("aeropend_bridge", "bridge.yaml", "aeropend_bridge", "bridge", "aeropend_bridge.bridge_node",
               ["-p", "autostart:=false"]),
    "sim": ("aeropend_sim", "sim.yaml", "aeropend_sim", "sim_node", "aeropend_sim.ros.sim_node", []),
}


def one_run(node: str, timeout: float, probe: bool, log: Path) -> dict:
    """One start of the node and one request, as the test does (``probe``: after
    :func:`ros_support.wait_for_server`, as the tests do now); returns what happened."""
    from rcl_interfaces.srv import GetParameters

    pkg, file, name, script, module, extra = NODES[node]
    path = ROOT / "src" / pkg / "config" / file
    with claim_domain(101, 200) as claim:
        cmd = [*node_command(script, module), "--ros-args", "--params-file", str(path), *extra]
        with log.open("w") as f:
            proc = subprocess.Popen(cmd, env=isolated_env(claim.domain_id), stdout=f,
                                    stderr=subprocess.STDOUT)
        out: dict = {"domain": claim.domain_id}
        try:
            with private_node("repro_client", claim.domain_id) as (n, executor):
                client = n.create_client(GetParameters, f"/{name}/get_parameters")
                t0 = time.monotonic()
                if probe:
                    out["probes_lost"] = wait_for_server(client, executor, GetParameters.Request(names=[]),
                                                         timeout)
                    out["available"] = True
                else:
                    out["available"] = bool(client.wait_for_service(timeout_sec=timeout))
                out["wait_s"] = round(time.monotonic() - t0, 3)
                if out["available"]:
                    for attempt in ("first", "second"):
                        fut = client.call_async(GetParameters.Request(names=["use_sim_time"]))
                        t1 = time.monotonic()
                        while not fut.done() and time.monotonic() < t1 + timeout:
                            executor.spin_once(timeout_sec=0.05)
                        out[f"{attempt}_answered"] = fut.done()
                        out[f"{attempt}_s"] = round(time.monotonic() - t1, 3)
                        if fut.done():
                            break
                n.destroy_client(client)
        finally:
            stop(proc, signal.SIGINT, timeout=15)
            reap(proc)
    text = log.read_text(errors="replace")
    out["server_dropped_response"] = "client will not receive response" in text
    if out["server_dropped_response"]:
        out["server_log"] = [ln for ln in text.splitlines() if "response" in ln][:3]
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=200)
    ap.add_argument("--hogs", type=int, default=1, help="CPU-bound processes running meanwhile")
    ap.add_argument("--node", default="bridge", choices=sorted(NODES))
    ap.add_argument("--timeout", type=float, default=20.0)
    ap.add_argument("--probe", action="store_true",
                    help="wait for the server both ways first (ros_support.wait_for_server), as the tests do")
    ap.add_argument("--out", default=str(ROOT / "bench" / "results" / "repro_param_service.json"))
    args = ap.parse_args(argv)
    hogs = [subprocess.Popen(HOG) for _ in range(args.hogs)]  # one busy core each, as bench_data_plane
    runs = []
    load0 = os.getloadavg()
    try:
        with tempfile.TemporaryDirectory() as tmp:
            for i in range(args.runs):
                r = one_run(args.node, args.timeout, args.probe, Path(tmp) / "node.log")
                runs.append(r)
                if not (r.get("available") and r.get("first_answered")) or r.get("probes_lost"):
                    print(f"run {i}: {r}", flush=True)
                elif i % 20 == 0:
                    print(f"run {i}: ok ({r['wait_s']} s wait, {r['first_s']} s answer)", flush=True)
    finally:
        for h in hogs:
            h.kill()
            h.wait()
    unanswered = [r for r in runs if r.get("available") and not r.get("first_answered")]
    answered = [r["first_s"] for r in runs if r.get("first_answered")]
    doc = {"node": args.node, "probe": args.probe, "runs": len(runs), "hogs": args.hogs,
           "load_before": load0, "load_after": os.getloadavg(),
           "unavailable": sum(not r.get("available") for r in runs),
           "first_request_unanswered": len(unanswered),
           "second_answered_after_a_lost_first": sum(bool(r.get("second_answered")) for r in unanswered),
           "answer_s_max": max(answered, default=None),
           "server_dropped_response": sum(bool(r.get("server_dropped_response")) for r in runs),
           "probes_lost": sum(r.get("probes_lost", 0) for r in runs),
           "wait_s_max": max((r.get("wait_s", 0.0) for r in runs), default=None),
           "failures": [r for r in runs if not (r.get("available") and r.get("first_answered"))]}
    Path(args.out).write_text(json.dumps(doc, indent=1), encoding="utf-8")
    print(json.dumps({k: v for k, v in doc.items() if k != "failures"}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
