"""Fake firmware on a pseudo-terminal, for tests, benchmarks and demos without hardware.

:class:`FakeMcu` opens a pty pair, publishes a stable symlink to the slave side (like a
``/dev/serial/by-id`` link) and writes sample frames of the real protocol at the firmware's
rate from a thread; it decodes the commands the bridge writes and applies them like the
firmware (duty, ENABLE, 250 ms command watchdog). Optional random byte corruption (seeded) records
which sample frames were damaged. :meth:`unplug` / :meth:`replug` close and reopen the pty.

Console script ``fake_mcu``: ``fake_mcu --link /tmp/aeropend_tty`` then
``bridge --ros-args -p port:=/tmp/aeropend_tty``.
"""

from __future__ import annotations

import argparse
import math
import os
import random
import select
import threading
import time
import tty
from pathlib import Path

from aeropend_bridge.protocol import (
    CH_I_A,
    CH_SPEED,
    CH_THETA,
    CH_V_A,
    FLAG_ENABLED,
    FLAG_WATCHDOG,
    PROTOCOL_VERSION,
    Duty,
    Enable,
    FrameDecoder,
    HelloFrame,
    HelloRequest,
    SampleFrame,
    StatusFrame,
    encode,
)

#: Firmware sample period [s]: Timer1 phase-correct 8-bit PWM, 510 ticks of 4 µs.
FIRMWARE_PERIOD_S = 2.040e-3
#: HELLO of the H-bridge firmware with the ADC angle (the build FakeMcu stands in for).
HBRIDGE_HELLO = HelloFrame(PROTOCOL_VERSION, 1, 1, CH_I_A | CH_V_A | CH_THETA | CH_SPEED, 490, 0, 0, 0, 249,
                           1024)
FIRMWARE_WATCHDOG_S = 0.25


class FakeMcu:
    """Pty-backed fake of the acquisition firmware.

    Parameters
    ----------
    link : str or Path
        Path of the symlink to the pty slave (replaced on :meth:`replug`).
    period_s : float
        Sample period (0 = as fast as possible, for soak tests).
    corrupt_p : float
        Probability that a written byte is replaced by a different random byte.
    seed : int
        Seed of the corruption and the signals.
    n_frames : int or None
        Stop after this many sample frames (None = run until :meth:`stop`).
    clean_tail : int
        The last ``clean_tail`` frames of ``n_frames`` are never corrupted.
    paused : bool
        Write nothing until :meth:`resume` (so a soak test starts after the reader connected;
        the bridge flushes stale input when it opens the port).
    plant : aeropend_sim.simulation.PlantStepper, optional
        Plant in the loop: each period applies the current duty (OCR/255) to the plant and sends
        its outputs as ADC counts / Timer4 ticks (inverse of ``calibration``).
    calibration : aeropend_bridge.bridge_core.Calibration, optional
        Count conversion for ``plant`` (required with it).
    hello : HelloFrame or None
        Answer to a HELLO request (default: the H-bridge / ADC-angle firmware, :data:`HBRIDGE_HELLO`);
        None behaves like protocol-1 firmware, which has no HELLO.
    """

    def __init__(self, link: str | Path, period_s: float = FIRMWARE_PERIOD_S, corrupt_p: float = 0.0,
                 seed: int = 0, n_frames: int | None = None, clean_tail: int = 5,
                 paused: bool = False, plant: object | None = None,
                 calibration: object | None = None, hello: HelloFrame | None = HBRIDGE_HELLO) -> None:
        self.link = Path(link)
        self.period_s = period_s
        self.corrupt_p = corrupt_p
        self.rng = random.Random(seed)
        self.n_frames = n_frames
        self.clean_tail = clean_tail
        self.sent: dict[int, SampleFrame] = {}  # index -> frame (index = frames written so far)
        self.corrupted: set[int] = set()         # indices of frames damaged on the line
        self.commands: list[tuple[float, object]] = []
        self.decoder = FrameDecoder()
        self.duty_ocr = 0
        self.enabled = True  # the firmware's output is enabled at reset
        self.watchdog_trips = 0
        #: time.monotonic() of each watchdog trip (a trip after the host's last command is the
        #: firmware doing its job once the host has gone)
        self.trip_times: list[float] = []
        #: the writer thread's largest lateness [s]: how long after its due time a frame went out (a
        #: stalled pytest process or host; the plant in the loop runs the backlog on the duty it held)
        self.max_lateness_s = 0.0
        self.done = threading.Event()
        self._master: int | None = None
        self._slave: int | None = None
        self._stop = threading.Event()
        self._plugged = threading.Event()
        self._thread: threading.Thread | None = None
        self._last_cmd = time.monotonic()
        self._wd = True
        self._applied = 0
        if plant is not None and calibration is None:
            raise ValueError("FakeMcu(plant=...) needs calibration= to convert outputs to counts")
        self.plant = plant
        self.cal = calibration
        self.hello = hello
        self._hello_due = False
        self._go = threading.Event()
        if not paused:
            self._go.set()

    # ------------------------------------------------------------------ pty
    def _open_pty(self) -> None:
        master, slave = os.openpty()
        tty.setraw(slave)
        tty.setraw(master)
        tmp = self.link.with_name(self.link.name + ".tmp")
        if tmp.is_symlink() or tmp.exists():
            tmp.unlink()
        tmp.symlink_to(os.ttyname(slave))
        tmp.replace(self.link)
        self._master, self._slave = master, slave
        self._plugged.set()

    def resume(self) -> None:
        """Start writing frames (see ``paused``)."""
        self._go.set()

    def unplug(self) -> None:
        """Close the pty (the bridge sees the device vanish)."""
        self._plugged.clear()
        for fd in (self._master, self._slave):
            if fd is not None:
                try:
                    os.close(fd)
                except OSError:
                    pass
        self._master = self._slave = None
        if self.link.is_symlink():
            self.link.unlink()

    def replug(self) -> None:
        """Open a new pty under the same link path."""
        self._open_pty()

    # ------------------------------------------------------------------ run
    def start(self) -> FakeMcu:
        """Open the pty and start the writer thread (a plant's compiled kernels loaded first: on the
        writer thread its first two frames took 6-10 ms each, against 0.06 ms after)."""
        if self.plant is not None:
            self.plant.warm()  # type: ignore[attr-defined]
        self._open_pty()
        self._thread = threading.Thread(target=self._run, name="fake_mcu", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        """Stop the thread and close the pty."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(2.0)
        self.unplug()

    def _plant_frame(self, k: int) -> SampleFrame:
        cal, plant = self.cal, self.plant
        if k > 0:
            plant.step(self._applied / 255.0)  # type: ignore[union-attr]
        y = plant.sample()  # type: ignore[union-attr]
        w = y["omega_prop"]
        period = round(2 * math.pi / (w * cal.tick_s)) if w > 0.5 else 0  # type: ignore[union-attr]
        theta = round((y["theta"] + cal.theta_offset) / cal.theta_lsb) % 1024  # type: ignore[union-attr]
        flags = self._flags()
        return SampleFrame(seq=k & 0xFFFF, t_us=round(k * FIRMWARE_PERIOD_S * 1e6) & 0xFFFFFFFF,
                           i_a=max(-1023, min(1023, round(y["i_a"] / cal.i_a_lsb))),  # type: ignore[union-attr]
                           v_a=max(-512, min(511, round(y["v_a"] / cal.v_a_lsb))),  # type: ignore[union-attr]
                           theta=theta, period=min(period, 2**32 - 1), duty=self._applied, flags=flags)

    @property
    def applied_ocr(self) -> int:
        """OCR value on the H-bridge: the commanded duty, 0 while the output is disabled."""
        return self.duty_ocr if self.enabled else 0

    def _flags(self) -> int:
        return (FLAG_ENABLED if self.enabled else 0) | (FLAG_WATCHDOG if self._wd else 0)

    def _frame(self, k: int) -> SampleFrame:
        if self.plant is not None:
            frame = self._plant_frame(k)
            self._applied = self.applied_ocr
            return frame
        t = k * self.period_s if self.period_s > 0 else k * FIRMWARE_PERIOD_S
        theta = 512 + int(200 * math.sin(2 * math.pi * 0.5 * t))
        return SampleFrame(seq=k & 0xFFFF, t_us=round(k * FIRMWARE_PERIOD_S * 1e6) & 0xFFFFFFFF,
                           i_a=100 + k % 7, v_a=-50 + k % 11, theta=theta, period=15000 + k % 13,
                           duty=self.applied_ocr, flags=self._flags())

    def _corrupt(self, wire: bytes, last_clean: bool, n_sample: int) -> tuple[bytes, bool, bool]:
        """Corrupt bytes of ``wire`` (sample frame = first ``n_sample`` bytes, maybe + status).

        Returns (bytes, sample frame hit, final delimiter hit: the next frame merges in).
        """
        if self.corrupt_p <= 0 or last_clean:
            return wire, False, False
        out = bytearray(wire)
        hit = delim_hit = False
        for i in range(len(out)):
            if self.rng.random() < self.corrupt_p:
                out[i] = (out[i] + self.rng.randint(1, 255)) & 0xFF
                hit |= i < n_sample
                delim_hit |= i == len(out) - 1
        return bytes(out), hit, delim_hit

    def _read_commands(self) -> None:
        fd = self._master
        if fd is None:
            return
        try:
            r, _, _ = select.select([fd], [], [], 0)
            if r:
                data = os.read(fd, 4096)
                now = time.monotonic()
                for f in self.decoder.feed(data):
                    self.commands.append((now, f))
                    self._last_cmd = now
                    if isinstance(f, Duty):
                        self.duty_ocr = (f.value * 255 + 32767) // 65535
                        self._wd = False
                    elif isinstance(f, Enable):
                        self.enabled = f.on
                    elif isinstance(f, HelloRequest) and self.hello is not None:
                        self._hello_due = True
        except OSError:
            pass
        if time.monotonic() - self._last_cmd > FIRMWARE_WATCHDOG_S and not self._wd:
            self._wd = True
            self.watchdog_trips += 1
            self.trip_times.append(time.monotonic())
            self.duty_ocr = 0

    def _due(self, k: int, t0: float) -> tuple[int, float]:
        """Frames due now: (index one past the last due frame, schedule anchor ``t0``).

        At least frame ``k`` is due; ``n_frames`` caps the index. A backlog longer than 0.5 s
        (a stalled process) is dropped by re-anchoring the schedule, not sent in one burst.
        """
        due = k + 1
        if self.period_s > 0:
            now = time.monotonic()
            self.max_lateness_s = max(self.max_lateness_s, now - t0 - k * self.period_s)
            if now - t0 - k * self.period_s > 0.5:
                t0 = now - k * self.period_s  # re-anchor after a long stall
            due = max(due, int((now - t0) / self.period_s) + 1)
        if self.n_frames is not None:
            due = min(due, self.n_frames)
        return due, t0

    def _run(self) -> None:
        """Writer loop: every frame due since the last wake-up goes out in one write.

        A wake-up that comes late (the thread waited for the GIL behind a busy thread of the
        same process, or the process was descheduled) catches up in one ``os.write``, as a USB
        CDC link delivers whatever the firmware queued since the last host poll. Writing frame
        by frame instead released and re-took the GIL two or three times per frame, so a busy
        Python thread beside it cut the rate to 124-177 Hz (``bench/repro/fake_mcu_gil_convoy.py``).
        """
        k = 0
        t0 = time.monotonic()
        while not self._stop.is_set():
            if self.n_frames is not None and k >= self.n_frames:
                self.done.set()
                self._stop.wait(0.05)
                self._read_commands()
                continue
            if not self._plugged.wait(0.05) or not self._go.wait(0.05):
                continue
            self._read_commands()
            due, t0 = self._due(k, t0)
            wire = bytearray()
            if self._hello_due:
                self._hello_due = False
                wire += encode(self.hello)  # type: ignore[arg-type]
            frames: list[tuple[int, SampleFrame, bool, bool]] = []
            for j in range(k, due):
                frame = self._frame(j)
                last_clean = self.n_frames is not None and j >= self.n_frames - self.clean_tail
                one = encode(frame)
                n_sample = len(one)
                if j % 256 == 255:
                    one += encode(StatusFrame(len(self.commands) & 0xFFFF, 0, 0, self.watchdog_trips, 0))
                one, hit, delim_hit = self._corrupt(one, last_clean, n_sample)
                wire += one
                frames.append((j, frame, hit, delim_hit))
            try:
                os.write(self._master, wire)  # type: ignore[arg-type]
            except (OSError, TypeError):
                continue  # unplugged between wait and write: frames k.. are re-sent after replug
            for j, frame, hit, delim_hit in frames:
                self.sent[j] = frame
                if hit:
                    self.corrupted.add(j)
                if delim_hit:
                    self.corrupted.add(j + 1)  # the next frame merges with this one
            k = due
            if self.period_s > 0:
                delay = t0 + k * self.period_s - time.monotonic()
                if delay > 0:
                    time.sleep(delay)


def main(argv: list[str] | None = None) -> int:
    """Console script ``fake_mcu``: serve fake firmware frames on a pty link until Ctrl-C."""
    ap = argparse.ArgumentParser(
        prog="fake_mcu",
        description="Fake aeropend firmware (protocol 1) on a pseudo-terminal, for running the bridge "
                    "without hardware: sample frames at the firmware's rate, duty / ENABLE commands and the "
                    "250 ms command watchdog applied like the firmware. Runs until Ctrl-C; no ROS.",
        epilog="Example: fake_mcu --link /tmp/aeropend_tty   then   "
               "bridge --ros-args -p port:=/tmp/aeropend_tty")
    ap.add_argument("--link", default="/tmp/aeropend_tty",
                    help="symlink to create for the pty slave (default /tmp/aeropend_tty)")
    ap.add_argument("--corrupt", type=float, default=0.0,
                    help="probability that a byte of a sample frame is corrupted (default 0)")
    a = ap.parse_args(argv)
    mcu = FakeMcu(a.link, corrupt_p=a.corrupt).start()
    print(f"fake MCU on {a.link} -> {os.path.realpath(a.link)}", flush=True)
    try:
        while True:
            time.sleep(1.0)
    except KeyboardInterrupt:
        pass
    finally:
        mcu.stop()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
