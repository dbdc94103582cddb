"""Start-up handshake of the simavr harness (``firmware/sim/harness``) for tests and benches.

The harness runs the real firmware on an emulated ATmega2560 and exposes its UART0 as a pty;
after simavr's own "Loaded ..." lines it prints ``PTY <path>`` on stdout (a name of the harness's
own, ``$TMPDIR/aeropend-simavr-<pid>.pty``, a symlink to the pty that it removes when it ends: a
link that reconnects after that finds nothing, not another harness's pty). The bridge (or a
:class:`~aeropend_bridge.serial_link.SerialLink`) then connects to that path like to a board;
:func:`harness_link` does both and tears them down; :func:`build_emulator` builds both programs.
"""

from __future__ import annotations

import contextlib
import os
import subprocess
import time
from collections.abc import Iterator, Sequence
from pathlib import Path

import numpy as np

from aeropend_bridge.serial_link import FrameCallback, SerialLink

#: simavr prints a few "Loaded ..." lines before the harness announces its pty.
MAX_STARTUP_LINES = 20
#: One swing of the emulated encoder's rod, an ``enc`` event line: (t0 [s], t1 [s], θ0 [rad], A [rad],
#: W [rad/s]), θ = θ0 + A·sin(W·(t − t0)) from t0 to t1 (after the firmware's Timer1 start), held after.
Swing = tuple[float, float, float, float, float]


def encoder_event_lines(swings: Sequence[Swing], cpr: int, index: int | None = None,
                        slip: tuple[float, int] | None = None) -> list[str]:
    """The event-file lines of an emulated quadrature encoder (``firmware/sim/harness.c``, ``-e``).

    Parameters
    ----------
    swings : sequence of Swing
        The rod's trajectory, in order.
    cpr : int
        Counts per revolution of the emulated encoder (``enccpr``).
    index : int, optional
        The disk count at which the gated index Z is high (``encindex``).
    slip : (float, int), optional
        (t [s], n): the first n counts the disk moves from t on do not reach the lines (``encslip``).
    """
    lines = [f"enccpr {cpr}"]
    if index is not None:
        lines.append(f"encindex {index}")
    if slip is not None:
        lines.append(f"encslip {slip[0] * 1e6:.1f} {slip[1]}")
    return lines + [f"enc {t0 * 1e6:.1f} {t1 * 1e6:.1f} {th0:.17g} {a:.17g} {w:.17g}"
                    for t0, t1, th0, a, w in swings]


def encoder_angle(swings: Sequence[Swing], t_s: np.ndarray) -> np.ndarray:
    """The emulated encoder's rod angle [rad] at times ``t_s`` [s] after the Timer1 start: the
    harness's ``enc_theta`` (0 before the first swing; each swing held after its end)."""
    t_s = np.asarray(t_s, dtype=float)
    th = np.zeros_like(t_s)
    for t0, t1, th0, a, w in swings:
        th = np.where(t_s >= t0, th0 + a * np.sin(w * (np.minimum(t_s, t1) - t0)), th)
    return th


class HarnessError(RuntimeError):
    """The harness ended or printed something else before announcing its pty."""


def read_pty_path(proc: subprocess.Popen[str], max_lines: int = MAX_STARTUP_LINES) -> str:
    """Read the harness's start-up lines until ``PTY <path>`` and return the path.

    Parameters
    ----------
    proc : subprocess.Popen
        The harness, started with ``stdout=PIPE, stderr=PIPE, text=True``.
    max_lines : int
        Start-up lines read at most before giving up.

    Returns
    -------
    str
        The pty device path (e.g. ``/dev/pts/7``).

    Raises
    ------
    HarnessError
        No ``PTY`` line within ``max_lines`` lines or before the harness closed stdout; the
        message holds the last line read and, if the harness has exited, its stderr.
    """
    if proc.stdout is None:
        raise HarnessError("the harness must be started with stdout=subprocess.PIPE")
    line = ""
    for _ in range(max_lines):
        line = proc.stdout.readline()
        if line.startswith("PTY ") or not line:
            break
    if not line.startswith("PTY "):
        err = proc.stderr.read() if proc.stderr is not None and proc.poll() is not None else ""
        raise HarnessError(f"simavr harness did not announce its pty: last line {line!r}; stderr: {err!r}")
    return line.split()[1]


def build_emulator(firmware_dir: str | Path, build_dir: str | Path, make_vars: Sequence[str] = (),
                   timeout_s: float = 300.0) -> Path:
    """Build the firmware's emulator variant and the harness into ``build_dir``.

    Parameters
    ----------
    firmware_dir : str or Path
        The repository's ``firmware/`` folder (its Makefile).
    build_dir : str or Path
        Output folder: ``aeropend.elf`` (built with ``-DSIMAVR_TIMER1``, see firmware/README.md) and
        ``harness``.
    make_vars : sequence of str
        The build's make variables, e.g. ``("ACTUATOR=esc", "ESC_HZ=490", "ANGLE=encoder")``.
    timeout_s : float
        Bound on the build [s].

    Returns
    -------
    Path
        ``build_dir``.

    Raises
    ------
    HarnessError
        make failed; the message holds its output.
    """
    r = subprocess.run(["make", "-C", str(firmware_dir), f"BUILD={build_dir}", *make_vars,
                        "EXTRA_CFLAGS=-DSIMAVR_TIMER1", "all", "harness"],
                       capture_output=True, text=True, timeout=timeout_s)
    if r.returncode != 0:
        raise HarnessError(f"building the emulator firmware ({' '.join(make_vars)}) failed:\n"
                           f"{r.stdout}{r.stderr}")
    return Path(build_dir)


def wait_drained(link: SerialLink, quiet_s: float = 0.5, timeout_s: float = 15.0) -> None:
    """Wait until ``link`` has read every byte the harness wrote: no byte for ``quiet_s`` seconds.

    Call it after the harness process ended, before leaving :func:`harness_link` (which stops the
    link): on a loaded host the reader runs behind the emulator, and a fixed pause cut off the
    run's last frames (226 of 2107 samples, 0.46 s of MCU time, in a parallel test run).
    ``timeout_s`` bounds the wait when bytes keep coming.
    """
    end = time.monotonic() + timeout_s
    seen, since = link.decoder.stats.bytes, time.monotonic()
    while time.monotonic() < end:
        time.sleep(0.05)
        now = link.decoder.stats.bytes
        if now != seen:
            seen, since = now, time.monotonic()
        elif time.monotonic() - since >= quiet_s:
            return


@contextlib.contextmanager
def harness_link(
    argv: Sequence[str], on_frame: FrameCallback
) -> Iterator[tuple[subprocess.Popen[str], SerialLink]]:
    """Start the harness and a started :class:`SerialLink` on its pty; stop both on exit.

    Parameters
    ----------
    argv : sequence of str
        Harness command line (``harness ELF CYCLES ...``).
    on_frame : callable
        Frame callback of the link, ``on_frame(frame, host_ns)`` (host clock ``time.monotonic_ns``).

    Yields
    ------
    proc, link
        The harness process (stdout/stderr piped, text) and the link; the caller waits for the
        connection (``link.wait_connected``).

    Raises
    ------
    HarnessError
        The harness did not announce its pty (:func:`read_pty_path`).

    On exit the link is stopped and a harness that is still running is killed and reaped (and the
    pty name it announced, a symlink it removes itself when it ends normally, removed).
    """
    proc = subprocess.Popen(list(argv), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    link = None
    path = None
    try:
        path = read_pty_path(proc)
        link = SerialLink(path, on_frame, clock_ns=time.monotonic_ns)
        link.start()
        yield proc, link
    finally:
        if link is not None:
            link.stop()
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
            if path is not None and os.path.islink(path):  # a killed harness cannot remove its name
                os.unlink(path)
