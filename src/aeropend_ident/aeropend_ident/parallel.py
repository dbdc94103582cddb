"""Independent cases on a Dask cluster: the benches, ``gap --sessions`` and ``gap-batch``.

:func:`run_cases` maps a function over independent cases (benchmark cases, sessions, recordings
of an archive) on a ``dask.distributed`` cluster and yields the results as they finish, with a
progress bar (:mod:`aeropend_ident.progress`). By default it starts a
:class:`distributed.LocalCluster` on this machine (``workers`` processes of one thread each, on
the loopback interface, its status page on a free port) and closes it afterwards; with ``scheduler="tcp://HOST:8786"``
it uses a lab's running cluster instead (``dask scheduler`` on one machine, ``dask worker
tcp://HOST:8786`` on each of the others: docs/gap.md, "Batches on a cluster").

Worker processes:

* are **spawned**, not forked (distributed's default): a numba thread pool or an OpenMP runtime
  of the parent is never copied into a child, so workers cannot hang on a lock held at fork time;
* replay on one thread each (:data:`aeropend_ident.greybox.batch.THREADS_ENV` = 1) and keep BLAS to
  one thread (threadpoolctl): a worker per core, nothing oversubscribed;
* read the compiled simulator from the same disk cache as this process (``AEROPEND_CACHE_DIR``,
  :mod:`aeropend_sim.compiled.source`), so a worker's first case loads the compiled plant in a
  fraction of a second instead of recompiling it (≈ 5 s per actuator family); on a lab cluster
  point ``AEROPEND_CACHE_DIR`` of the workers at a shared or pre-warmed folder.

A case function is sent by reference: an importable module's function by its module name, a
function of a script (a bench run as ``python bench/x.py``) by its file, which the worker imports
with the script's folder on its path (so the script's sibling modules import too). The case
arguments and results travel by pickle.

No rclpy import: this module runs without ROS.
"""

from __future__ import annotations

import contextlib
import importlib
import importlib.util
import inspect
import logging
import os
import sys
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import Any

from aeropend_control.design_gains import WORKERS_ENV as DESIGN_WORKERS_ENV
from aeropend_ident.greybox.batch import THREADS_ENV, one_blas_thread
from aeropend_ident.progress import bar

#: Environment of every worker of a local cluster: one replay thread, one BLAS/OpenMP thread and
#: ``design_gains``'s strategies checked in the worker itself (no process pool inside a pool).
WORKER_ENV = {THREADS_ENV: "1", "OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1",
              DESIGN_WORKERS_ENV: "1"}


def default_workers() -> int:
    """Workers of a local cluster: one per available core."""
    return max(1, len(os.sched_getaffinity(0)))


def _local_workers(workers: int | None) -> int:
    """Worker processes of a local cluster for ``workers`` (None: one per core)."""
    return default_workers() if workers is None else int(workers)


def _in_this_process(n: int, scheduler: str | None) -> bool:
    """Whether :func:`run_cases` runs its cases in the calling process: one local worker."""
    return scheduler is None and n == 1


def engine_label(workers: int | None, scheduler: str | None) -> str:
    """Where :func:`run_cases` runs its cases, for a result file's meta: ``"dask ADDRESS"`` (a
    running scheduler), ``"dask LocalCluster"`` or ``"this process, one case at a time"``
    (``workers`` = 1 without a scheduler)."""
    if _in_this_process(_local_workers(workers), scheduler):
        return "this process, one case at a time"
    return f"dask {scheduler or 'LocalCluster'}"


def _reference(func: Callable[..., Any]) -> tuple[str, str, str]:
    """(module name, file, qualified name) that a worker imports ``func`` by."""
    name = func.__qualname__
    if "<" in name:
        raise ValueError(f"{name!r} is not a module-level function; a cluster worker cannot import it")
    return func.__module__, str(Path(inspect.getfile(func)).resolve()), name


def _resolve(module: str, file: str) -> Any:
    """The case function's module in a worker: by name, or a script by its file."""
    if module != "__main__":
        try:
            return importlib.import_module(module)
        except ImportError:
            pass
    stem = "_aeropend_case_" + Path(file).stem
    if stem in sys.modules:
        return sys.modules[stem]
    folder = str(Path(file).parent)
    if folder not in sys.path:
        sys.path.insert(0, folder)
    spec = importlib.util.spec_from_file_location(stem, file)
    if spec is None or spec.loader is None:
        raise ImportError(f"cannot import the case function's script {file}")
    mod = importlib.util.module_from_spec(spec)
    sys.modules[stem] = mod
    spec.loader.exec_module(mod)
    return mod


def call_case(ref: tuple[str, str, str], case: Any) -> Any:
    """Run one case in a worker: the worker settings of the module doc, then ``func(case)``."""
    for key, value in WORKER_ENV.items():
        os.environ.setdefault(key, value)
    module, file, name = ref
    func: Any = _resolve(module, file)
    for part in name.split("."):
        func = getattr(func, part)
    with one_blas_thread():
        return func(case)


def _silence_cluster_logs() -> None:
    """Run on each worker (and here) when a run is interrupted: its shutdown chatter is no news."""
    for name in ("distributed", "asyncio", "tornado"):  # "task exception never retrieved" of a
        logging.getLogger(name).setLevel(logging.CRITICAL + 1)  # cluster stopped while it started


def _sigint_ignoring_python() -> str | None:
    """Path of a launcher of this Python with SIGINT ignored (None where it cannot be made).

    A two-line shell script (``trap "" INT``, then ``exec`` of ``sys.executable``) kept in
    ``$TMPDIR/aeropend-UID/`` (one per interpreter); None on a system without ``/bin/sh``, a folder
    that cannot be written or one mounted ``noexec`` (the workers then start as before).
    """
    if os.name != "posix" or not os.path.exists("/bin/sh"):
        return None
    import hashlib
    import shlex
    import tempfile

    folder = Path(tempfile.gettempdir()) / f"aeropend-{os.getuid()}"
    # one launcher per interpreter (two environments on one machine do not share it)
    path = folder / f"python-sigint-ignored-{hashlib.sha256(sys.executable.encode()).hexdigest()[:12]}"
    text = ("#!/bin/sh\n# aeropend: Python with SIGINT ignored (local Dask workers: the command handles "
            f"Ctrl-C)\ntrap '' INT\nexec {shlex.quote(sys.executable)} \"$@\"\n")
    try:
        folder.mkdir(parents=True, exist_ok=True)
        if os.statvfs(folder).f_flag & os.ST_NOEXEC:
            return None
        if not (path.is_file() and path.read_text(encoding="utf-8") == text and os.access(path, os.X_OK)):
            tmp = folder / f".{path.name}.{os.getpid()}"
            tmp.write_text(text, encoding="utf-8")
            tmp.chmod(0o755)
            os.replace(tmp, path)
    except OSError:
        return None
    return str(path)


def _ignore_sigint() -> None:
    """Run on each local worker's main thread: Ctrl-C at a terminal reaches the whole process group,
    but only the command handles it (it closes the cluster and says so in one line)."""
    import signal

    signal.signal(signal.SIGINT, signal.SIG_IGN)


def _quiet_shutdown(client: Any) -> None:
    """Before the cluster of an interrupted run closes: no "task cancelled" or "worker killed"
    warnings around the command's one-line message (issue 62)."""
    _silence_cluster_logs()
    with contextlib.suppress(Exception):
        client.run(_silence_cluster_logs)


def _close_half_started() -> None:
    """Close a local cluster whose start was interrupted (Ctrl-C while its workers start).

    Its constructor never returned, so only distributed's own list of clusters knows it; left
    there, distributed's exit handler prints a traceback closing it.
    """
    _silence_cluster_logs()
    from distributed.deploy.spec import SpecCluster

    for cluster in list(getattr(SpecCluster, "_instances", ())):
        with contextlib.suppress(BaseException):
            cluster.close(timeout=10)
        cluster.shutdown_on_close = False  # nothing left for the exit handler to report


def _cluster(workers: int, scheduler: str | None) -> Any:
    from distributed import Client, LocalCluster

    if scheduler:
        return Client(scheduler), None
    # a worker killed at Ctrl-C leaves its semaphores to the resource tracker, which would warn at exit
    os.environ.setdefault("PYTHONWARNINGS", "ignore:resource_tracker:UserWarning")
    env = dict(WORKER_ENV)
    if os.environ.get("AEROPEND_CACHE_DIR"):
        env["AEROPEND_CACHE_DIR"] = os.environ["AEROPEND_CACHE_DIR"]
    # Ctrl-C at a terminal reaches the whole process group: the workers start through a launcher
    # that ignores SIGINT (a disposition a new process keeps; Python then installs no handler), so
    # only this command handles it, closes the cluster and says so in one line
    from multiprocessing import spawn

    python = spawn.get_executable()
    launcher = _sigint_ignoring_python()
    if launcher is not None:
        spawn.set_executable(launcher)
    try:
        cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, host="127.0.0.1",
                               dashboard_address=":0", env=env)
    finally:
        spawn.set_executable(python)
    client = Client(cluster)
    client.run(_ignore_sigint)
    return client, cluster


def run_cases(func: Callable[[Any], Any], cases: Sequence[Any], *, workers: int | None = None,
              scheduler: str | None = None, desc: str = "cases", quiet: bool = False
              ) -> Iterator[tuple[int, Any]]:
    """Run ``func(case)`` for every case on a Dask cluster; yield ``(index, result)`` as they finish.

    Parameters
    ----------
    func : callable
        A module-level function of one argument (module doc: sent by reference).
    cases : sequence
        Picklable case descriptions.
    workers : int, optional
        Worker processes of the local cluster (default one per core); 1 without ``scheduler`` runs
        the cases in this process, one after the other (no cluster); ignored with ``scheduler``.
    scheduler : str, optional
        Address of a running scheduler (``tcp://host:8786``) instead of a local cluster.
    desc : str
        Label of the progress bar.
    quiet : bool
        No progress bar.

    Raises
    ------
    ValueError
        If ``func`` cannot be sent by reference, or ``workers`` < 1.
    Exception
        A case's own exception, re-raised here (catch inside ``func`` to record failures as
        results instead).
    """
    from distributed import as_completed

    ref = _reference(func)
    n = _local_workers(workers)
    if n < 1:
        raise ValueError(f"workers = {workers!r}; expected >= 1")
    if not cases:
        return
    if _in_this_process(n, scheduler):  # one case after the other
        with bar(len(cases), desc, quiet=quiet, unit="case") as progress:
            for i, case in enumerate(cases):
                result = func(case)
                progress.update(1)
                yield i, result
        return
    try:
        client, cluster = _cluster(n, scheduler)
    except BaseException:
        if scheduler is None:
            _close_half_started()
        raise
    progress = bar(len(cases), desc, quiet=quiet, unit="case")
    try:
        futures = {client.submit(call_case, ref, case, pure=False): i for i, case in enumerate(cases)}
        for fut in as_completed(futures):
            i = futures[fut]
            result = fut.result()
            progress.update(1)
            yield i, result
    except BaseException:  # Ctrl-C, a full disk, a case's error: the command says it in one line
        _quiet_shutdown(client)
        raise
    finally:
        progress.close()
        client.close()
        if cluster is not None:
            cluster.close()
