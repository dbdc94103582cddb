"""The suite gives the commands its tests start Ctrl-C as a terminal does, even when it was itself
started with SIGINT ignored (a background job of a script: bash's ``cmd &``; test/conftest.py)."""

from __future__ import annotations

import signal
import subprocess
import sys
from pathlib import Path

CONFTEST = Path(__file__).with_name("conftest.py")

#: In a process started with SIGINT ignored: optionally import test/conftest.py, then report whether
#: a command started from there has SIGINT ignored too.
PROBE = """
import importlib.util, subprocess, sys
if sys.argv[2] == "conftest":
    spec = importlib.util.spec_from_file_location("aeropend_test_conftest", sys.argv[1])
    spec.loader.exec_module(importlib.util.module_from_spec(spec))
child = "import signal; print(signal.getsignal(signal.SIGINT) is signal.SIG_IGN)"
out = subprocess.run([sys.executable, "-c", child], capture_output=True, text=True, check=True)
print(out.stdout.strip())
"""


def _child_ignores_sigint(with_conftest: bool) -> bool:
    out = subprocess.run([sys.executable, "-c", PROBE, str(CONFTEST), "conftest" if with_conftest else "-"],
                         capture_output=True, text=True, check=True, timeout=60,
                         preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_IGN))
    return {"True": True, "False": False}[out.stdout.strip()]


def test_a_suite_started_with_sigint_ignored_starts_commands_that_take_ctrl_c() -> None:
    assert _child_ignores_sigint(with_conftest=False), "premise: an ignored SIGINT is inherited"
    assert not _child_ignores_sigint(with_conftest=True)
