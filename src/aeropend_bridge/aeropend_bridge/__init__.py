"""Serial bridge to the Arduino Mega acquisition firmware: the public API of its functional core.

The bridge node (:mod:`aeropend_bridge.bridge_node`, rclpy) publishes the same topics as the
simulated plant (:mod:`aeropend_sim.contract`); what it is built from has no rclpy and is exported
here: the frame codec of the serial protocol (COBS framing, CRC-16, the sample/status/command
frames, an incremental :class:`FrameDecoder`), the bridge's core (calibration to SI units, the
firmware clock mapped to ROS time, sequence gaps, the command watchdog, the firmware handshake),
the serial link with reconnection, and a fake firmware on a pty for tests without hardware::

    from aeropend_bridge import Duty, FrameDecoder, SampleFrame, encode
    line = encode(Duty.from_fraction(0.4))         # bytes for the serial port (τ = 0.4)
    frames = FrameDecoder().feed(received_bytes)   # SampleFrame / StatusFrame objects

Importing the package is cheap (the codec is plain Python; pyserial only), so the names are
imported eagerly. Submodules import their siblings directly, never this file. Reference:
docs/api.md; the wire format: docs/hardware.md.
"""

from aeropend_bridge.bridge_core import (
    BridgeConfigError,
    BridgeStats,
    Calibration,
    ClockMapper,
    CommandWatchdog,
    FirmwareError,
    FirmwareHandshake,
    SequenceTracker,
)
from aeropend_bridge.fake_mcu import FakeMcu
from aeropend_bridge.protocol import (
    BAUD,
    Calibrate,
    DecoderStats,
    Duty,
    Enable,
    Frame,
    FrameDecoder,
    ProtocolError,
    Rate,
    SampleFrame,
    StatusFrame,
    cobs_decode,
    cobs_encode,
    crc16,
    encode,
    encode_frame,
    parse_payload,
)
from aeropend_bridge.serial_link import SerialLink

__all__ = [
    "BAUD",
    "BridgeConfigError",
    "BridgeStats",
    "Calibrate",
    "Calibration",
    "ClockMapper",
    "CommandWatchdog",
    "DecoderStats",
    "Duty",
    "Enable",
    "FakeMcu",
    "FirmwareError",
    "FirmwareHandshake",
    "Frame",
    "FrameDecoder",
    "ProtocolError",
    "Rate",
    "SampleFrame",
    "SequenceTracker",
    "SerialLink",
    "StatusFrame",
    "cobs_decode",
    "cobs_encode",
    "crc16",
    "encode",
    "encode_frame",
    "parse_payload",
]
