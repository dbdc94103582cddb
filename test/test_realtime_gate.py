"""The real-time verdict gate of ``test/conftest.py``: a test marked ``exclusive`` that fails while the
host steals CPU time is reported as skipped with the steal and the failure; nothing else changes."""

from __future__ import annotations

import time
from pathlib import Path

import pytest

from aeropend_sim.ros.harness import STEAL_LIMIT, cpu_times, steal_share

pytest_plugins = ["pytester"]

STAT = "cpu  {user} 0 {system} {idle} 10 0 5 {steal} 0 0\ncpu0 1 2 3 4 5 6 7 8 0 0\n"

FAKE_HOST = """
import itertools
import aeropend_sim.ros.harness as harness
_n = itertools.count()
def _fake():  # every reading: 1000 ticks more, of which STEAL stolen
    k = next(_n)
    return round(k * 1000 * STEAL), k * 1000
harness.cpu_times = _fake
"""

TESTS = """
import pytest
@pytest.mark.exclusive
def test_exclusive_fails():
    assert 1 == 2, "the loop was starved"
@pytest.mark.exclusive
def test_exclusive_passes():
    pass
def test_ordinary_fails():
    assert 1 == 2
"""


def test_cpu_times_reads_the_steal_and_the_total() -> None:
    stat = STAT.format(user=700, system=100, idle=150, steal=35)
    assert cpu_times(stat) == (35, 700 + 100 + 150 + 10 + 5 + 35)
    assert cpu_times("cpu  1 2 3 4\n") is None          # no steal field
    assert cpu_times("intr 1 2 3 4 5 6 7 8 9\n") is None  # not the cpu line
    assert isinstance(cpu_times(), tuple) or cpu_times() is None  # this host's own file


def test_steal_share_is_the_stolen_part_of_the_time_between_two_readings() -> None:
    assert steal_share((10, 1000), (60, 2000)) == pytest.approx(0.05)
    assert steal_share(None, (60, 2000)) is None
    assert steal_share((10, 1000), (10, 1000)) is None


def _run(pytester: pytest.Pytester, steal: float) -> pytest.RunResult:
    pytester.makeconftest(Path(__file__).with_name("conftest.py").read_text())
    pytester.makepyfile(fake_host=FAKE_HOST.replace("STEAL", repr(steal)))
    pytester.makepyfile(test_gate="import fake_host  # noqa: F401\n" + TESTS)
    return pytester.runpytest_subprocess("-p", "no:cacheprovider", "-rsf", "-p", "no:xdist")


def test_a_real_time_failure_under_steal_is_withheld_and_named(pytester: pytest.Pytester) -> None:
    result = _run(pytester, steal=0.10)
    result.assert_outcomes(passed=1, failed=1, skipped=1)
    result.stdout.fnmatch_lines(["*verdict withheld: the host took 10.0% of the CPU time (steal)*"
                                 "*it failed with: AssertionError: the loop was starved*"])
    result.stdout.fnmatch_lines(["FAILED*test_ordinary_fails*"])  # not exclusive: a failure stays one


def test_without_steal_a_real_time_failure_stays_a_failure(pytester: pytest.Pytester) -> None:
    result = _run(pytester, steal=STEAL_LIMIT / 2)
    result.assert_outcomes(passed=1, failed=2)


def test_busy_share_counts_all_but_idle_and_iowait() -> None:
    from aeropend_sim.ros.harness import busy_share

    lines = iter(["cpu  100 0 50 800 50 0 0 0 0 0\n", "cpu  160 0 70 900 70 0 0 0 0 0\n"])
    # 80 busy (user 60, system 20) of 200 ticks
    assert busy_share(0.0, stat=lambda: next(lines)) == pytest.approx(0.4)
    assert busy_share(0.0, stat=lambda: "cpu  1 2\n") is None


def test_wait_until_idle_returns_at_once_on_an_idle_machine_and_gives_up_on_a_busy_one(monkeypatch) -> None:
    from aeropend_sim.ros import harness

    monkeypatch.setattr(harness, "busy_share", lambda window: 0.01)
    assert harness.wait_until_idle(timeout=5.0) < 1.0
    monkeypatch.setattr(harness, "busy_share", lambda window: (time.sleep(window), 0.9)[1])
    assert 0.3 <= harness.wait_until_idle(timeout=0.3, window=0.05) < 1.0
