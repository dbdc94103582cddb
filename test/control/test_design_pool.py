"""The worker processes of a design's closed loops (:func:`aeropend_control.design_gains.design_pool`)
end with the process that started them.

A design killed with SIGKILL or SIGTERM runs no clean-up: before the parent watch, its spawned
workers stayed behind for good, idle, 240 MB each (``excitation_design --mode reference`` sent
SIGTERM 25 s into its search: both workers still there a minute later)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

import pytest

#: The parent: a pool of one worker that tells its pid, then waits to be killed.
PARENT = """
import os, sys, time
from aeropend_control.design_gains import design_pool
if __name__ == "__main__":
    pool = design_pool(1)
    print(pool.submit(os.getpid).result(), flush=True)
    time.sleep(60)
"""


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    with open(f"/proc/{pid}/stat", encoding="ascii") as f:  # a zombie is gone but for its parent's wait
        return f.read().rsplit(")", 1)[1].split()[0] != "Z"


@pytest.mark.parametrize("sig", [signal.SIGKILL, signal.SIGTERM])
def test_a_worker_ends_when_the_design_that_started_it_is_killed(sig: signal.Signals) -> None:
    parent = subprocess.Popen([sys.executable, "-c", PARENT], stdout=subprocess.PIPE, text=True)
    try:
        worker = int(parent.stdout.readline())
        assert _alive(worker)
        parent.send_signal(sig)
        parent.wait(10)
        deadline = time.monotonic() + 10.0
        while _alive(worker) and time.monotonic() < deadline:
            time.sleep(0.1)
        assert not _alive(worker), f"worker {worker} outlived its parent killed by {sig.name}"
    finally:
        parent.kill()
