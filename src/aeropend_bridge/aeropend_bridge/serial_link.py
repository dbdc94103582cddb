"""Serial link to the firmware (pyserial, no rclpy): reader thread, reconnect, command writes.

:class:`SerialLink` opens the port, decodes every byte with
:class:`~aeropend_bridge.protocol.FrameDecoder` and hands each frame with its host receive time
to a callback, from its own thread. On any I/O error (cable unplugged, pty closed) it closes
the port, counts a reconnect and tries again with exponential backoff until stopped.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable

import serial

from aeropend_bridge.bridge_core import Backoff
from aeropend_bridge.protocol import BAUD, Frame, FrameDecoder, encode

FrameCallback = Callable[[Frame, int], None]
EventCallback = Callable[[str], None]


class SerialLink:
    """Reader thread + writer of one serial port.

    Parameters
    ----------
    port : str
        Device path (e.g. ``/dev/ttyACM0``, a ``/dev/serial/by-id`` link or a pty).
    on_frame : callable(frame, host_ns)
        Called from the reader thread for every valid frame; ``host_ns`` is
        ``clock_ns()`` when the chunk containing the frame's end was read.
    baud : int
        Line rate (500000, see PROTOCOL.md).
    clock_ns : callable
        Host time source [ns] (the node passes ROS time).
    on_event : callable(str), optional
        Log sink for connect/disconnect messages.
    on_connect : callable(), optional
        Called from the reader thread after each (re)connection (e.g. to resend state).
    backoff : Backoff, optional
        Reconnection delays.
    """

    def __init__(self, port: str, on_frame: FrameCallback, baud: int = BAUD,
                 clock_ns: Callable[[], int] = time.time_ns, on_event: EventCallback | None = None,
                 on_connect: Callable[[], None] | None = None, backoff: Backoff | None = None) -> None:
        self.port = port
        self.baud = int(baud)
        self.on_frame = on_frame
        self.clock_ns = clock_ns
        self.on_event = on_event or (lambda msg: None)
        self.on_connect = on_connect
        self.backoff = backoff or Backoff()
        self.decoder = FrameDecoder()
        self.connects = 0
        self.disconnects = 0
        self.write_errors = 0
        self._ser: serial.Serial | None = None
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._connected = threading.Event()
        self._thread: threading.Thread | None = None

    # ------------------------------------------------------------------ lifecycle
    def start(self) -> None:
        """Start the reader thread (it connects by itself)."""
        self._thread = threading.Thread(target=self._run, name="aeropend_serial", daemon=True)
        self._thread.start()

    def stop(self, timeout: float = 2.0) -> None:
        """Stop the reader thread and close the port (idempotent)."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout)
            self._thread = None
        self._close()

    @property
    def connected(self) -> bool:
        """True while the port is open."""
        return self._connected.is_set()

    def wait_connected(self, timeout: float) -> bool:
        """Block until connected or ``timeout`` [s]; return whether connected."""
        return self._connected.wait(timeout)

    # ------------------------------------------------------------------ writing
    def send(self, frame: Frame) -> bool:
        """Encode and write one command frame; False if not connected or the write failed."""
        data = encode(frame)
        with self._lock:
            ser = self._ser
            if ser is None:
                return False
            try:
                ser.write(data)
                return True
            except (serial.SerialException, OSError, ValueError):
                self.write_errors += 1
                return False

    # ------------------------------------------------------------------ reader
    def _open(self) -> bool:
        try:
            ser = serial.Serial(self.port, self.baud, timeout=0.02, write_timeout=0.1)
        except (serial.SerialException, OSError, ValueError) as exc:
            self.on_event(f"cannot open {self.port}: {exc}")
            return False
        with self._lock:
            self._ser = ser
        self.decoder.feed(b"\x00")  # drop any partial frame from before
        try:
            ser.reset_input_buffer()
            ser.write(b"\x00")  # terminate a partial command frame on the MCU side
        except (serial.SerialException, OSError):
            pass
        self.connects += 1
        self.backoff.reset()
        self._connected.set()
        self.on_event(f"connected to {self.port} at {self.baud} baud (connection {self.connects})")
        if self.on_connect is not None:
            self.on_connect()
        return True

    def _close(self) -> None:
        self._connected.clear()
        with self._lock:
            ser, self._ser = self._ser, None
        if ser is not None:
            try:
                ser.close()
            except (serial.SerialException, OSError):
                pass

    def _run(self) -> None:
        while not self._stop.is_set():
            if self._ser is None and not self._open():
                self._stop.wait(self.backoff.next_delay())
                continue
            ser = self._ser
            try:
                n = ser.in_waiting if ser is not None else 0
                data = ser.read(max(1, n)) if ser is not None else b""
            except (serial.SerialException, OSError, TypeError, AttributeError) as exc:
                if self._stop.is_set():
                    break
                self.disconnects += 1
                self.on_event(f"lost {self.port}: {exc}; reconnecting")
                self._close()
                self.decoder.feed(b"\x00")
                self._stop.wait(self.backoff.next_delay())
                continue
            if not data:
                continue
            now = self.clock_ns()
            for frame in self.decoder.feed(data):
                self.on_frame(frame, now)
