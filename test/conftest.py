"""Shared fixtures and the test markers.

The markers are registered here rather than in an ini file so that both ways of running the
tests know them: ``./scripts/test.sh`` (pytest from the root, ``pyproject.toml``) and
``colcon test`` (pytest in each package with its ``setup.cfg``, this file through
``--confcutdir``).
"""

from __future__ import annotations

import os
import signal
import sys
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path

import pytest

#: In a pytest-xdist worker (``scripts/test.sh`` runs the suite in several): one replay thread and one
#: BLAS/OpenMP thread per worker, as every pool or cluster worker of the product runs
#: (``aeropend_ident.parallel.WORKER_ENV``). The workers are the parallelism; a worker that also
#: split its replays and BLAS products over every core ran 4 workers x 2 threads on 2 cores, and
#: OpenBLAS threads spinning against the other workers made CPU-bound tests time out after 600 s
#: (docs/findings/test_suite.md). Set before numpy is imported, so OpenBLAS starts with one thread.
#: Likewise ``design_gains`` checks its strategies one after the other in a worker
#: (``aeropend_control.design_gains.WORKERS_ENV``), not in a process pool of its own.
PARALLEL_WORKER_ENV = {"AEROPEND_REPLAY_THREADS": "1", "OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1",
                       "MKL_NUM_THREADS": "1", "AEROPEND_DESIGN_WORKERS": "1"}
if os.environ.get("PYTEST_XDIST_WORKER"):
    for _key, _value in PARALLEL_WORKER_ENV.items():
        os.environ.setdefault(_key, _value)

#: Ctrl-C as a terminal gives it. A script or CI runner that starts the suite as a background job
#: without job control (bash's ``cmd &``) starts it with SIGINT ignored, and every command a test
#: starts inherits that disposition: the tests that interrupt a command (csv_import's and gap-batch's
#: Ctrl-C, bridge_check stopping the fake MCU) then saw it ignored and failed, 3 of them in every such
#: run (test/test_sigint_inherited.py). A handler, unlike "ignored", is not inherited across exec.
if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
    signal.signal(signal.SIGINT, signal.default_int_handler)

#: Columns of a CSV log written by ``bench/fixtures/truth_plant.py`` (``TruthRecording.to_csv``).
TRUTH_CSV_COLUMNS = {"i_a": "i_a_A", "v_a": "v_a_V", "omega_rotor": "omega_rad_s"}

MARKERS = (
    "ros: real multi-process ROS 2 test (rclpy nodes in separate processes)",
    "real_data: reads third-party recordings from ../shared/data/real",
    "slow: takes more than ~20 s in the parallel suite on a loaded 2-core machine (~5 s alone), or "
    "shares a module fixture that does; -m 'not ros and not slow' is the fast subset (docs/testing.md)",
    "exclusive: a real-time hardware-in-the-loop test that needs the machine to itself (its loop is "
    "starved beside other tests on 2 cores); scripts/test.sh runs these one at a time after the "
    "parallel part (docs/testing.md)",
    # pytest-xdist's own marker, registered here too so --strict-markers knows it without xdist
    "xdist_group(name): under --dist loadgroup, every test of the group runs on one worker "
    "(a module whose fixture is expensive computes it once)",
)


def pytest_configure(config: pytest.Config) -> None:
    for marker in MARKERS:
        config.addinivalue_line("markers", marker)
    if os.environ.get("PYTEST_XDIST_WORKER") and "numpy" in sys.modules:
        # numpy came first (a plugin): limit its already started BLAS pool for the whole worker
        from threadpoolctl import threadpool_limits

        threadpool_limits(limits=1)


#: Environment variable through which ``scripts/test.sh`` has its run of the ``exclusive`` tests alone
#: import only the test files that hold one, instead of collecting the whole suite a second time
#: (12 s for 12 tests in 10 files on this machine): ``list:TOKEN`` in the parallel run, which stores
#: those files in pytest's cache (``.pytest_cache``, under the run's root folder) with the token;
#: ``only:TOKEN`` in the run alone, which collects just the stored files when the token is the same
#: (else, e.g. when the parallel run stopped before it collected, everything as usual).
EXCLUSIVE_FILES_ENV = "AEROPEND_EXCLUSIVE_FILES"
_EXCLUSIVE_KEY = "aeropend/exclusive_files"
#: the stored exclusive files of this run (None: collect as usual), read once
_LISTED = pytest.StashKey["set[str] | None"]()


def _exclusive_mode() -> tuple[str, str]:
    """(``"list"``, ``"only"`` or ``""``, the run's token) from :data:`EXCLUSIVE_FILES_ENV`."""
    mode, _, token = os.environ.get(EXCLUSIVE_FILES_ENV, "").partition(":")
    return (mode, token) if mode in ("list", "only") and token else ("", "")


def _listed_exclusive_files(config: pytest.Config) -> set[str] | None:
    """The test files the parallel run of the same token stored (absolute paths), or None."""
    mode, token = _exclusive_mode()
    cache = getattr(config, "cache", None)
    if mode != "only" or cache is None:
        return None
    stored = cache.get(_EXCLUSIVE_KEY, None)
    if not isinstance(stored, dict) or stored.get("token") != token:
        return None
    return set(stored.get("files", ()))


def pytest_ignore_collect(collection_path: Path, config: pytest.Config) -> bool | None:
    """In the run of the ``exclusive`` tests alone, leave out the test files the parallel run found
    none in (a folder is still walked; a file that is not a test module is collected as usual)."""
    if _LISTED not in config.stash:
        config.stash[_LISTED] = _listed_exclusive_files(config)
    listed = config.stash[_LISTED]
    if listed is None or collection_path.is_dir() or not collection_path.name.startswith("test_"):
        return None
    return str(collection_path.resolve()) not in listed or None


def _store_exclusive_files(config: pytest.Config, items: Sequence[pytest.Item]) -> None:
    """Store the files of the items marked ``exclusive`` with the run's token (every xdist worker
    collects the same items and stores the same value). The first collection of a token is the
    run's own: a pytest that a test starts in the same folder inherits the variable
    (``test_workspace`` collects one package's tests to count them) and is collected after every
    worker, so a list already stored under the token is kept."""
    mode, token = _exclusive_mode()
    cache = getattr(config, "cache", None)
    if mode != "list" or cache is None:
        return
    stored = cache.get(_EXCLUSIVE_KEY, None)
    if isinstance(stored, dict) and stored.get("token") == token:
        return
    files = sorted({str(Path(item.path).resolve()) for item in items if item.get_closest_marker("exclusive")})
    cache.set(_EXCLUSIVE_KEY, {"token": token, "files": files})


def pytest_runtest_setup(item: pytest.Item) -> None:
    """In ``scripts/test.sh``'s run of the ``exclusive`` tests alone, wait (at most 20 s) until the
    CPUs are idle before each: that run starts as soon as the parallel part ends, and a real-time
    test must not share the machine with processes of that part still exiting or writing back
    (``aeropend_sim.ros.harness.wait_until_idle``); a wait over 1 s is listed in the test's report."""
    if item.get_closest_marker("exclusive") is None or _exclusive_mode()[0] != "only":
        return
    from aeropend_sim.ros.harness import IDLE_LIMIT, wait_until_idle

    waited = wait_until_idle()
    if waited > 1.0:
        item.add_report_section("setup", "idle wait", f"waited {waited:.1f} s for the CPUs to be busy under "
                                f"{IDLE_LIMIT:.0%} before this real-time test")


@pytest.hookimpl(tryfirst=True)  # before the -m selection deselects the exclusive tests
def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """Run the test modules that hold a test marked ``slow`` first, the others after, each module's tests
    together and in their collected order (and list the files of the ``exclusive`` tests for
    ``scripts/test.sh``'s run of them alone: :data:`EXCLUSIVE_FILES_ENV`).

    pytest-xdist hands the work out in this order (an ``xdist_group`` as one unit, the larger groups
    first), and a 100 s test handed out last leaves the other workers idle while it runs: the CI of
    fa1041f spent 17:07 on the parallel part for 29:50 of CPU on 2 cores. Longest first is the
    classic rule for sharing jobs out; the marker is this suite's knowledge of which are long. A
    module stays whole so that its module fixtures are not computed once for each part.
    """
    def module(item: pytest.Item) -> str:
        return item.nodeid.split("::")[0]

    _store_exclusive_files(config, items)
    slow = {module(item) for item in items if item.get_closest_marker("slow") is not None}
    items.sort(key=lambda item: module(item) not in slow)  # a stable sort: the modules with slow tests first


#: (before, after) :func:`~aeropend_sim.ros.harness.cpu_times` readings around an exclusive test's call
_STEAL = pytest.StashKey[tuple]()


@pytest.hookimpl(wrapper=True)
def pytest_runtest_call(item: pytest.Item) -> Iterator[None]:
    """Read the CPU steal around the call of a test marked ``exclusive`` (see the report hook)."""
    if item.get_closest_marker("exclusive") is None:
        return (yield)
    from aeropend_sim.ros.harness import cpu_times

    before = cpu_times()
    try:
        return (yield)
    finally:
        item.stash[_STEAL] = (before, cpu_times())


@pytest.hookimpl(wrapper=True)
def pytest_runtest_makereport(item: pytest.Item, call: pytest.CallInfo) -> Iterator[pytest.TestReport]:
    """Withhold the verdict of a real-time test that failed while the host took the CPU away.

    A test marked ``exclusive`` runs a real-time loop that needs both cores. When, during its call,
    the hypervisor gave more than :data:`~aeropend_sim.ros.harness.STEAL_LIMIT` of the machine's CPU
    time to other guests (``/proc/stat`` steal), a failure says nothing about aeropend: the report
    becomes a skip that names the steal and the failure, listed in pytest's summary. A pass stays a
    pass, and a failure with the CPU to itself stays a failure (docs/testing.md).
    """
    report = yield
    if call.when != "call" or not report.failed or _STEAL not in item.stash:
        return report
    from aeropend_sim.ros.harness import STEAL_LIMIT, steal_share

    share = steal_share(*item.stash[_STEAL])
    if share is None or share <= STEAL_LIMIT:
        return report
    excinfo = call.excinfo
    failure = (f"{excinfo.typename}: {str(excinfo.value).strip().splitlines()[0][:200]}"
               if excinfo is not None and str(excinfo.value).strip() else "a failure")
    report.outcome = "skipped"
    report.longrepr = (str(item.path), item.location[1] or 0,
                       f"Skipped: verdict withheld: the host took {share:.1%} of the CPU time (steal) "
                       f"during this real-time test, over the {STEAL_LIMIT:.0%} it can absorb; it "
                       f"failed with: {failure}")
    return report


@pytest.fixture(autouse=True)
def _domain_claims_released() -> Iterator[None]:
    """Give back the ROS domain IDs a test claimed (``random_domain``) once it is over.

    A claim otherwise lasts as long as its process, and a pytest worker lives for the whole run:
    the parallel workers of this suite and the suites and benchmarks of other checkouts on the
    same host would fill the claimed ranges between them. The test's node processes are stopped
    by then (every test reaps them in a ``finally``); claims of module-scoped fixtures are made
    before this fixture starts and are kept.
    """
    from aeropend_sim.ros.harness import claimed_domains, release_domains

    held = claimed_domains()
    yield
    release_domains(keep=held)


@pytest.fixture
def truth_csv_preset(monkeypatch: pytest.MonkeyPatch) -> Callable[..., str]:
    """Register a ``csv_import`` preset for the independent truth plant's CSV logs, for this test.

    Call it with a preset name and the extra channels to read (default i_a, v_a, ω₁); it returns
    the name (for ``FILE.csv:NAME`` arguments). The preset is removed after the test.
    """
    from aeropend_ident.io import csv_import
    from aeropend_ident.io.csv_import import CsvSpec

    def register(name: str, channels: Sequence[str] = tuple(TRUTH_CSV_COLUMNS)) -> str:
        spec = CsvSpec(angle_col="theta_rad", angle_unit="rad", time_col="time_s", time_unit="s",
                       input_col="duty", input_kind="duty",
                       channels={c: (TRUTH_CSV_COLUMNS[c], 1.0) for c in channels})
        monkeypatch.setitem(csv_import.PRESETS, name, spec)
        return name

    return register


@pytest.fixture
def saved_figures(monkeypatch: pytest.MonkeyPatch) -> list:
    """Every matplotlib Figure saved during the test, in order (recorded as ``savefig`` is called).

    Figure tests inspect what was drawn (titles, legend entries, axis limits, notes) on these
    objects instead of only checking that a PNG exists; the figures are still written as usual.
    """
    from matplotlib.figure import Figure

    saved: list = []
    original = Figure.savefig

    def record(self, *args, **kwargs):
        saved.append(self)
        return original(self, *args, **kwargs)

    monkeypatch.setattr(Figure, "savefig", record)
    return saved
