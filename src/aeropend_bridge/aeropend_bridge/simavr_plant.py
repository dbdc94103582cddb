"""A rig file's simulated plant behind the simavr harness: pulse in, rod angle out (issue 61).

The harness (``firmware/sim/harness.c``, option ``-P SOCKET``) runs the real ESC + encoder firmware
and, every fixed interval of MCU time, sends the width of the last complete pulse on the ESC pin and
blocks until it reads back the rod angle; its emulated encoder then follows that angle. This module
serves that socket: the pulse becomes τ through the rig file's own ESC calibration
(:meth:`aeropend_bridge.family.CommandMap.tau_of_pulse`, the map the bridge uses), aeropend's
simulator of the rig (:class:`aeropend_sim.simulation.PlantStepper`, what ``sim_node`` steps)
advances by the interval with that τ, and the true angle goes back (the firmware's encoder does the
quantising). A lab can so try its firmware build against its fitted rig file before flashing::

    python -m aeropend_bridge.simavr_plant fitted.yaml /tmp/plant.sock &
    firmware/build/harness firmware/build/aeropend.elf 0 -P /tmp/plant.sock

Wire format (native byte order): harness → plant ``{double t [s] since reset, double pulse [s]}``,
plant → harness ``{double theta [rad]}``. The pulse received at t is held until the next exchange
(zero-order hold, as an ESC holds the last frame's width); the angle sent at t is the rod's at t.

Functional core :class:`PulsePlant` (no sockets), the server :func:`serve` and the command line
:func:`main`.
"""

from __future__ import annotations

import argparse
import contextlib
import csv
import dataclasses
import math
import os
import socket
import stat
import struct
import sys
from collections.abc import Callable
from pathlib import Path
from typing import BinaryIO, TextIO

import numpy as np

from aeropend_bridge.family import CommandMap, read_rig_hardware
from aeropend_sim.params import load_rig
from aeropend_sim.simulation import PlantStepper

#: Harness → plant record: t [s], pulse [s].
REQUEST = struct.Struct("=dd")
#: Plant → harness record: θ [rad].
REPLY = struct.Struct("=d")
#: Columns of the exchange trace (``--trace``): MCU time [s], pulse width [s], τ held from then [1],
#: θ sent back [rad].
TRACE_COLUMNS = ("t_s", "pulse_s", "tau", "theta_rad")
#: Default exchange interval [s] (the harness's ``-Q 1000``).
DEFAULT_INTERVAL_S = 1.0e-3


class PlantProtocolError(RuntimeError):
    """The harness sent something the plant cannot apply (time going back, a non-finite value)."""


class PulsePlant:
    """The rig's plant driven by ESC pulse widths at a fixed interval (no sockets).

    Parameters
    ----------
    rig_ref : str or Path
        Rig file (path to a .yaml, or a shipped rig's name) of an ESC rig; its ``hardware`` block
        gives the pulse calibration (default 1.0–2.0 ms).
    interval_s : float
        Exchange interval [s]: the simulator's step (the rig's ``sample_period`` is replaced by it;
        the input delay and every other parameter stay).
    x0 : sequence of float, optional
        Initial state [θ rad, θ̇ rad/s, i_a A, ω_rotor rad/s, τ_f] (default at rest, hanging).

    Attributes
    ----------
    t : float
        Plant time [s] (the state is the rod's at ``t``).
    tau : float
        τ held since the last exchange [1].
    exchanges : int
        Exchanges served.
    tau_max : float
        Largest τ applied so far [1].

    Raises
    ------
    FamilyMismatchError
        If no aeropend firmware drives the rig's family (from :meth:`CommandMap.for_rig`).
    ValueError
        If the rig is not an ESC rig or ``interval_s`` is not positive.
    """

    def __init__(self, rig_ref: str | Path, interval_s: float = DEFAULT_INTERVAL_S,
                 x0: list[float] | None = None) -> None:
        if not (interval_s > 0 and math.isfinite(interval_s)):
            raise ValueError(f"interval_s = {interval_s!r} must be a finite positive number of seconds")
        rig = load_rig(rig_ref)
        hw = read_rig_hardware(rig_ref, rig.family, rig.name)
        self.cmap = CommandMap.for_rig(hw)
        if self.cmap.actuator != "esc":
            raise ValueError(f"rig {rig.name!r} is a {rig.family} rig; the pulse plant drives an ESC rig")
        # the true angle: the firmware's encoder quantises it, so no sensor noise or quantisation here
        rig = dataclasses.replace(rig.with_effects(sensor_noise=False, quantisation=False),
                                  sample_period=float(interval_s))
        self.stepper = PlantStepper(rig, x0=None if x0 is None else np.asarray(x0, dtype=float))
        self.dt = float(interval_s)
        self.t = 0.0
        self.tau = 0.0
        self.exchanges = 0
        self.tau_max = 0.0

    @property
    def theta(self) -> float:
        """Rod angle at :attr:`t` [rad] (true, unquantised)."""
        return float(self.stepper.x[0])

    def exchange(self, t_s: float, pulse_s: float) -> float:
        """Advance to ``t_s`` with the τ held since the last exchange, then hold ``pulse_s``'s τ.

        Parameters
        ----------
        t_s : float
            MCU time of the exchange [s] since reset; the plant steps by the interval while it is
            more than half an interval behind (one step per exchange at the harness's fixed interval).
        pulse_s : float
            Width of the last complete pulse on the ESC pin [s] (0 before the first pulse: τ 0).

        Returns
        -------
        float
            θ(t_s) [rad].

        Raises
        ------
        PlantProtocolError
            If a value is not finite or ``t_s`` lies more than half an interval before :attr:`t`.
        """
        if not (math.isfinite(t_s) and math.isfinite(pulse_s)):
            raise PlantProtocolError(f"non-finite exchange t = {t_s!r} s, pulse = {pulse_s!r} s")
        if t_s < self.t - self.dt / 2:
            raise PlantProtocolError(f"time went back: t = {t_s:.6f} s < plant time {self.t:.6f} s")
        while self.t + self.dt / 2 <= t_s:
            self.stepper.step(self.tau)
            self.t += self.dt
        self.tau = self.cmap.tau_of_pulse(pulse_s)
        self.tau_max = max(self.tau_max, self.tau)
        self.exchanges += 1
        return self.theta


def serve(path: str | Path, plant: PulsePlant, on_listen: Callable[[str], None] | None = None,
          accept_timeout_s: float = 60.0, trace: TextIO | None = None) -> int:
    """Serve one harness on the Unix stream socket ``path`` until it closes the connection.

    Parameters
    ----------
    path : str or Path
        Socket path (an old socket there is replaced; removed on return).
    plant : PulsePlant
    on_listen : callable, optional
        Called with ``path`` once the socket listens (e.g. to print a ready line).
    accept_timeout_s : float
        How long [s] to wait for the harness to connect.
    trace : text file, optional
        Receives one CSV row per exchange (:data:`TRACE_COLUMNS`: MCU time [s], pulse width [s], the
        τ it holds [1], θ sent back [rad]) after a header row.

    Returns
    -------
    int
        Exchanges served.

    Raises
    ------
    FileExistsError
        If ``path`` exists and is not a socket (it is left as it is).
    TimeoutError
        If no harness connects in time.
    PlantProtocolError
        On a bad record (see :meth:`PulsePlant.exchange`).
    """
    path = str(path)
    with contextlib.suppress(FileNotFoundError):
        if not stat.S_ISSOCK(os.lstat(path).st_mode):  # never a user's file: only an old socket goes
            raise FileExistsError(f"{path} exists and is not a socket; choose another socket path")
        os.unlink(path)
    srv = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    try:
        srv.bind(path)
        srv.listen(1)
        srv.settimeout(accept_timeout_s)
        if on_listen is not None:
            on_listen(path)
        conn, _ = srv.accept()
        conn.settimeout(None)
        rows = csv.writer(trace) if trace is not None else None
        if rows is not None:
            rows.writerow(TRACE_COLUMNS)
        with conn:
            rfile = conn.makefile("rb", buffering=0)
            while True:
                buf = _read_exact(rfile, REQUEST.size)
                if buf is None:
                    return plant.exchanges
                t_s, pulse_s = REQUEST.unpack(buf)
                theta = plant.exchange(t_s, pulse_s)
                conn.sendall(REPLY.pack(theta))
                if rows is not None:
                    rows.writerow((repr(t_s), repr(pulse_s), repr(plant.tau), repr(theta)))
    finally:
        srv.close()
        with contextlib.suppress(FileNotFoundError):
            os.unlink(path)


def _read_exact(f: BinaryIO, n: int) -> bytes | None:
    """``n`` bytes, or None at the end of the stream."""
    buf = b""
    while len(buf) < n:
        part = f.read(n - len(buf))
        if not part:
            return None
        buf += part
    return buf


def main(argv: list[str] | None = None) -> int:
    """Command line: ``python -m aeropend_bridge.simavr_plant RIG SOCKET [--interval S] [--trace CSV]``.

    Prints ``LISTENING <socket>`` once the harness may connect and ``PLANT exchanges=<n> t=<s>
    theta=<rad> tau_max=<1>`` when it has disconnected; ``--trace CSV`` writes every exchange to a new
    file. Exit status 0, 2 on a bad rig, argument or trace path (an existing file is never
    overwritten), 1 on a protocol error.
    """
    ap = argparse.ArgumentParser(prog="python -m aeropend_bridge.simavr_plant",
                                 description="Serve a rig file's simulated plant to the simavr harness "
                                             "(harness ... -P SOCKET): ESC pulse in, rod angle out.")
    ap.add_argument("rig", help="ESC rig file (.yaml) or shipped rig name")
    ap.add_argument("socket", help="Unix socket path the harness connects to (-P)")
    ap.add_argument("--interval", type=float, default=DEFAULT_INTERVAL_S,
                    help="exchange interval [s], the harness's -Q in seconds (default 0.001)")
    ap.add_argument("--accept-timeout", type=float, default=60.0, help="wait for the harness [s]")
    ap.add_argument("--trace", metavar="CSV", type=Path,
                    help="write one row per exchange (t_s, pulse_s, tau, theta_rad) to this new file")
    args = ap.parse_args(argv)
    try:
        plant = PulsePlant(args.rig, args.interval)
    except (OSError, ValueError) as exc:
        print(f"simavr_plant: {exc}", file=sys.stderr)
        return 2
    with contextlib.ExitStack() as stack:
        try:  # "x": a trace never overwrites a file
            trace = stack.enter_context(args.trace.open("x", newline="")) if args.trace else None
        except OSError as exc:
            print(f"simavr_plant: cannot create the trace {args.trace}: {exc.strerror}", file=sys.stderr)
            return 2
        try:
            serve(args.socket, plant, lambda p: print(f"LISTENING {p}", flush=True), args.accept_timeout,
                  trace)
        except (PlantProtocolError, TimeoutError, FileExistsError) as exc:
            print(f"simavr_plant: {exc}", file=sys.stderr)
            return 1
    print(f"PLANT exchanges={plant.exchanges} t={plant.t:.6f} theta={plant.theta:.6f} "
          f"tau_max={plant.tau_max:.4f}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
