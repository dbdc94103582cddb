"""``scripts/test.sh``'s run of the ``exclusive`` tests alone imports only the test files the parallel run
found them in (``test/conftest.py``, ``AEROPEND_EXCLUSIVE_FILES``): the same tests run, without
collecting the whole suite a second time; a token of another run (a stale list) collects everything."""

from __future__ import annotations

from pathlib import Path

import pytest

pytest_plugins = ["pytester"]

ALONE = """
import pytest

@pytest.mark.exclusive
def test_real_time():
    pass

def test_plain_beside_it():
    pass
"""
PLAIN = "def test_plain():\n    pass\n"
# a module whose import fails: collected, it is an error; left out, nothing happens
BROKEN = "raise RuntimeError('imported')\n\ndef test_never():\n    pass\n"


@pytest.fixture
def suite(pytester: pytest.Pytester) -> pytest.Pytester:
    pytester.makeconftest(Path(__file__).with_name("conftest.py").read_text())
    pytester.makepyfile(test_alone=ALONE, test_plain=PLAIN)
    return pytester


def _run(pytester: pytest.Pytester, monkeypatch: pytest.MonkeyPatch, value: str,
         marks: str) -> pytest.RunResult:
    monkeypatch.setenv("AEROPEND_EXCLUSIVE_FILES", value)
    return pytester.runpytest_subprocess("-p", "no:xdist", "-m", marks, "-q")


def test_the_run_alone_collects_only_the_files_the_parallel_run_listed(suite, monkeypatch) -> None:
    _run(suite, monkeypatch, "list:run1", "not exclusive").assert_outcomes(passed=2, deselected=1)
    suite.makepyfile(test_broken=BROKEN)  # would fail the collection if it were imported
    alone = _run(suite, monkeypatch, "only:run1", "exclusive")
    alone.assert_outcomes(passed=1, deselected=1)
    assert "imported" not in alone.stdout.str()


def test_a_list_of_another_run_collects_everything(suite, monkeypatch) -> None:
    _run(suite, monkeypatch, "list:run1", "not exclusive").assert_outcomes(passed=2, deselected=1)
    suite.makepyfile(test_broken=BROKEN)
    stale = _run(suite, monkeypatch, "only:run2", "exclusive")
    stale.assert_outcomes(errors=1)  # the broken module was imported: a full collection
    assert "imported" in stale.stdout.str()


def test_a_pytest_started_by_a_test_keeps_the_runs_list(suite, monkeypatch) -> None:
    """A test that starts pytest in the same folder (``test_workspace`` counts a package's tests)
    inherits the token; its collection of a part of the suite must not replace the run's list."""
    _run(suite, monkeypatch, "list:run1", "not exclusive").assert_outcomes(passed=2, deselected=1)
    monkeypatch.setenv("AEROPEND_EXCLUSIVE_FILES", "list:run1")
    suite.runpytest_subprocess("-p", "no:xdist", "-q", "test_plain.py").assert_outcomes(passed=1)
    _run(suite, monkeypatch, "only:run1", "exclusive").assert_outcomes(passed=1, deselected=1)
