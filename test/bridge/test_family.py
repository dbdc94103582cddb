"""The rig file's hardware against the firmware's HELLO, and the one τ -> DUTY / PULSE map (issue 61).

No ROS, no serial port: :mod:`aeropend_bridge.family` and the absent-channel handling of
:class:`~aeropend_bridge.bridge_core.Calibration` with real numbers.
"""

from __future__ import annotations

import math
from pathlib import Path

import pytest
import yaml

from aeropend_bridge.bridge_core import Calibration
from aeropend_bridge.family import (
    CommandMap,
    FamilyMismatchError,
    HardwareError,
    check_firmware,
    legacy_hello,
    read_rig_hardware,
)
from aeropend_bridge.protocol import (
    ABSENT_I16,
    ABSENT_U32,
    CH_INDEX,
    CH_SPEED,
    CH_THETA,
    FLAG_ANGLE_INVALID,
    FLAG_ANGLE_SSI,
    FLAG_ANGLE_UNHOMED,
    Duty,
    HelloFrame,
    ProtocolError,
    Pulse,
    PulseSampleFrame,
    SampleFrame,
)
from aeropend_ident.cli.rig import main as rig_main
from aeropend_sim.params import load_rig

ESC_HELLO = HelloFrame(2, 2, 3, CH_THETA | CH_SPEED, 50, 1000, 2000, 2000, 61, 4000)
HB_HELLO = HelloFrame(2, 1, 1, 0x0F, 490, 0, 0, 0, 249, 1024)


def _q(value: float, unit: str) -> dict:
    return {"value": value, "unit": unit, "source": "test"}


@pytest.fixture
def esc_rig(tmp_path: Path) -> Path:
    """An ESC rig file from `rig new` with an encoder and a 1.1-2.0 ms ESC calibration."""
    out = tmp_path / "esc_enc.yaml"
    assert rig_main(["new", "--actuator", "esc", "-o", str(out)]) == 0
    data = yaml.safe_load(out.read_text())
    data["hardware"] = {"angle_sensor": "encoder", "counts_per_rev": _q(4000, "1"),
                        "pulse_offset": _q(1.1e-3, "s"), "pulse_span": _q(0.9e-3, "s")}
    out.write_text(yaml.safe_dump(data))
    return out


def test_rig_file_hardware_block_is_read_and_accepted_by_load_rig(esc_rig: Path) -> None:
    rig = load_rig(esc_rig)  # the loader accepts (and ignores) the block
    hw = read_rig_hardware(esc_rig, rig.family, rig.name)
    assert (hw.family, hw.actuator, hw.angle_sensor, hw.counts_per_rev) == ("esc", "esc", "encoder", 4000)
    assert (hw.pulse_offset, hw.pulse_span) == (1.1e-3, 0.9e-3)
    thesis = read_rig_hardware("thesis_rig", load_rig("thesis_rig").family)
    assert (thesis.actuator, thesis.angle_sensor, thesis.counts_per_rev) == ("hbridge", None, None)


@pytest.mark.parametrize("block, message", [
    ({"angle_sensor": "imu"}, "angle_sensor 'imu' is not one of"),
    ({"counts_per_rev": {"value": 4000, "unit": "1"}}, "counts_per_rev has no source"),
    ({"pulse_offset": _q(1.0, "ms")}, "pulse_offset has unit 'ms'; expected 's'"),
    ({"pulse_span": _q(-1e-3, "s")}, "pulse_span = -0.001 must be a finite positive"),
    ({"counts_per_rev": _q(4000.5, "1")}, "must be a whole number"),
    ({"frame_rate": _q(50, "Hz")}, "unknown hardware key(s) ['frame_rate']"),
    ({"angle_sensor": "encoder", "encoder_index": "yes"}, "encoder_index 'yes' must be true or false"),
    ({"angle_sensor": "pot", "encoder_index": True}, "an index belongs to an encoder"),
])
def test_malformed_hardware_block_names_the_key(esc_rig: Path, block: dict, message: str) -> None:
    data = yaml.safe_load(esc_rig.read_text())
    data["hardware"] = block
    esc_rig.write_text(yaml.safe_dump(data))
    with pytest.raises(HardwareError) as exc:
        read_rig_hardware(esc_rig, "esc")
    assert message in str(exc.value) and str(esc_rig) in str(exc.value)


def test_matching_firmware_is_accepted(esc_rig: Path) -> None:
    check_firmware(read_rig_hardware(esc_rig, "esc"), ESC_HELLO, 2 * math.pi / 4000)
    thesis = read_rig_hardware("thesis_rig", "dc_hbridge")
    check_firmware(thesis, HB_HELLO, 2 * math.pi / 1024)
    # protocol-1 firmware (no HELLO): H-bridge with the ADC angle, or SSI (flag bit 6)
    ssi = legacy_hello(SampleFrame(0, 2040, 1, 2, 3, 0, 0, FLAG_ANGLE_SSI))
    assert (ssi.actuator_name, ssi.sensor_name, ssi.counts_per_rev) == ("hbridge", "ssi", 1024)
    check_firmware(thesis, ssi, 2 * math.pi / 1024)


def test_mismatches_are_refused_by_name(esc_rig: Path, tmp_path: Path) -> None:
    esc = read_rig_hardware(esc_rig, "esc", "my_esc")
    thesis = read_rig_hardware("thesis_rig", "dc_hbridge", "thesis_rig")
    with pytest.raises(FamilyMismatchError, match=r"rig 'my_esc' is a esc rig \(firmware actuator 'esc'\) "
                                                   r"but the firmware on the port drives 'hbridge'"):
        check_firmware(esc, HB_HELLO)
    with pytest.raises(FamilyMismatchError, match=r"rig 'thesis_rig' is a dc_hbridge rig.*drives 'esc'"):
        check_firmware(thesis, ESC_HELLO)
    enc_hb = HelloFrame(2, 1, 3, 0x0F, 490, 0, 0, 0, 249, 4000)
    with pytest.raises(FamilyMismatchError, match=r"names no hardware\.angle_sensor.*reads 'encoder'"):
        check_firmware(thesis, enc_hb)
    with pytest.raises(FamilyMismatchError, match="states 4000 counts per revolution but the firmware "
                                                  "counts 8000"):
        check_firmware(esc, HelloFrame(2, 2, 3, 4, 50, 1000, 2000, 2000, 61, 8000))
    with pytest.raises(FamilyMismatchError, match=r"theta_quantum 0.00613592 rad is not 2π/4000"):
        check_firmware(esc, ESC_HELLO, 2 * math.pi / 1024)
    narrow = HelloFrame(2, 2, 3, 4, 50, 1150, 1900, 2000, 61, 4000)
    with pytest.raises(FamilyMismatchError, match=r"maps τ 0..1 to 1100..2000 µs but the firmware's pulse "
                                                   r"range is 1150..1900 µs"):
        check_firmware(esc, narrow)
    va = tmp_path / "va.yaml"
    assert rig_main(["new", "--actuator", "voltage_amplifier", "-o", str(va)]) == 0
    with pytest.raises(FamilyMismatchError, match="voltage_amplifier rig: no aeropend firmware drives it"):
        check_firmware(read_rig_hardware(va, "voltage_amplifier"), HB_HELLO)
    with pytest.raises(FamilyMismatchError, match="no aeropend firmware drives a voltage_amplifier rig"):
        CommandMap.for_rig(read_rig_hardware(va, "voltage_amplifier"))


def test_command_map_esc_and_hbridge(esc_rig: Path) -> None:
    esc = CommandMap.for_rig(read_rig_hardware(esc_rig, "esc"))  # 1.1 ms + τ·0.9 ms
    assert esc.off() == Pulse(2200)
    assert esc.command(1.0) == Pulse(4000)
    assert esc.command(0.25) == Pulse(round((1.1e-3 + 0.25 * 0.9e-3) / 0.5e-6)) == Pulse(2650)
    assert esc.command(1 / 3).half_us == 2800  # 1.4 ms
    for tau in (0.0, 0.25, 0.5, 0.75, 1.0):
        f = PulseSampleFrame(1, 2040, ABSENT_I16, ABSENT_I16, 0, ABSENT_U32, 0, 0,
                             pulse=esc.command(tau).half_us)
        assert esc.applied(f) == pytest.approx(tau, abs=0.5e-6 / 0.9e-3)
    below = PulseSampleFrame(1, 2040, 0, 0, 0, 0, 0, 0, pulse=2000)  # 1.0 ms: below zero throttle
    assert esc.applied(below) == 0.0
    for bad in (math.nan, -0.01, 1.01):
        with pytest.raises(ProtocolError):
            esc.command(bad)
    hb = CommandMap.for_rig(read_rig_hardware("thesis_rig", "dc_hbridge"))
    assert hb.command(0.5) == Duty(32768) and hb.off() == Duty(0)
    assert hb.applied(SampleFrame(1, 2040, 0, 0, 0, 0, 110, 1)) == pytest.approx(110 / 255)


def test_absent_channels_are_nan_never_zero() -> None:
    cal = Calibration(i_a_lsb=5 / 1024, v_a_lsb=2.56 / 512, theta_lsb=2 * math.pi / 4000, gear_ratio=2.0)
    f = PulseSampleFrame(7, 2040, ABSENT_I16, ABSENT_I16, 1000, ABSENT_U32, 0, 0, pulse=3000)
    s = cal.to_sample(f, 5, duty=0.5)
    assert math.isnan(s.i_a) and math.isnan(s.v_a) and math.isnan(s.omega_prop) and math.isnan(s.omega_rotor)
    assert s.theta == pytest.approx(math.pi / 2) and s.duty == 0.5
    # a measured zero stays zero; a rig without the channel (LSB 0) gives NaN
    z = cal.to_sample(SampleFrame(7, 2040, 0, 0, 0, 0, 0, 0), 5)
    assert (z.i_a, z.v_a, z.omega_prop, z.duty) == (0.0, 0.0, 0.0, 0.0)
    no_arm = Calibration(i_a_lsb=0.0, v_a_lsb=0.0, theta_lsb=2 * math.pi / 1024)
    n = no_arm.to_sample(SampleFrame(7, 2040, 12, 34, 0, 0, 0, 0), 5)
    assert math.isnan(n.i_a) and math.isnan(n.v_a)


def test_encoder_index_stated_in_the_rig_must_match_the_firmware(esc_rig: Path) -> None:
    """hardware.encoder_index: true needs an index build (HELLO CH_INDEX), false refuses one (it
    would never home); unstated accepts either."""
    data = yaml.safe_load(esc_rig.read_text())
    index_hello = HelloFrame(2, 2, 3, CH_THETA | CH_INDEX, 50, 1000, 2000, 2000, 61, 4000)
    assert read_rig_hardware(esc_rig, "esc").encoder_index is None
    check_firmware(read_rig_hardware(esc_rig, "esc"), index_hello)
    check_firmware(read_rig_hardware(esc_rig, "esc"), ESC_HELLO)
    for stated, hello, message in ((True, ESC_HELLO, "has no index input: flash an ENC_INDEX build"),
                                   (False, index_hello, "homes on an index (an ENC_INDEX build)")):
        data["hardware"]["encoder_index"] = stated
        esc_rig.write_text(yaml.safe_dump(data))
        hw = read_rig_hardware(esc_rig, "esc", "my_esc")
        assert hw.encoder_index is stated
        with pytest.raises(FamilyMismatchError, match=r"rig 'my_esc' says its encoder's index is") as exc:
            check_firmware(hw, hello)
        assert message in str(exc.value)
        check_firmware(hw, index_hello if stated else ESC_HELLO)


def test_unhomed_encoder_angle_is_nan() -> None:
    """An index build's θ before the first index edge is not in the rod's frame: NaN; a build
    without an index never reads the bit as homing (in SSI builds it is the linearity alarm)."""
    homing = Calibration(i_a_lsb=0.0, v_a_lsb=0.0, theta_lsb=2 * math.pi / 4000, homing=True)
    unhomed = SampleFrame(7, 2040, ABSENT_I16, ABSENT_I16, 1000, ABSENT_U32, 0, FLAG_ANGLE_UNHOMED)
    homed = SampleFrame(8, 4080, ABSENT_I16, ABSENT_I16, 1000, ABSENT_U32, 0, FLAG_ANGLE_INVALID)
    assert not homing.homed(unhomed) and math.isnan(homing.to_sample(unhomed, 5).theta)
    assert homing.homed(homed) and homing.to_sample(homed, 5).theta == pytest.approx(math.pi / 2)
    plain = Calibration(i_a_lsb=0.0, v_a_lsb=0.0, theta_lsb=2 * math.pi / 4000)
    assert plain.homed(unhomed) and plain.to_sample(unhomed, 5).theta == pytest.approx(math.pi / 2)
