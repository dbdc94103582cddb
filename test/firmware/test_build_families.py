"""Every actuator × angle-sensor build of the firmware compiles, and the new frames are byte-compatible
between the C and the Python codec (issue 61).

Builds: ``ACTUATOR`` ∈ {hbridge, esc} × ``ANGLE`` ∈ {pwm, ssi, encoder}, the ESC at both ends of
its frame range (50, 490 Hz), ``SPEED=none``: warning-free (-Werror), a few kB of flash, and the
interrupt vectors each build relies on implemented (encoder: INT2 = vector 3, INT3 = 4; its index,
``ENC_INDEX``: INT0 = 1, in index builds only; every
build: TIMER1_OVF = 20; the ESC build's Timer3 is a hardware PWM without an interrupt in the
production build). Bad choices stop the build with a message naming the variable: an ESC frame
rate outside 50–490 Hz, a watchdog silence + frame over 100 ms, counts per revolution beyond 16
bits, an index outside the revolution or without an encoder, an unknown actuator.

Codec: a host program links ``firmware/src/protocol.c`` and prints the HELLO and SAMPLE_PULSE
payloads it packs, its command parser's view of PULSE and HELLO_REQ, and the quadrature decoder's
table; each is compared with :mod:`aeropend_bridge.protocol` and an independent x4 decoding.
"""

from __future__ import annotations

import itertools
import re
import shutil
import subprocess
from pathlib import Path

import pytest

from aeropend_bridge.protocol import (
    ABSENT_I16,
    ABSENT_U32,
    CH_INDEX,
    FLAG_ANGLE_UNHOMED,
    HelloFrame,
    HelloRequest,
    Pulse,
    PulseSampleFrame,
    parse_payload,
)

ROOT = Path(__file__).resolve().parents[2]
FW = ROOT / "firmware"

pytestmark = pytest.mark.skipif(shutil.which("avr-gcc") is None or shutil.which("make") is None,
                                reason="needs avr-gcc + make (scripts/setup_env.sh installs them)")

BUILDS = {f"{act}_{ang}": [f"ACTUATOR={act}", f"ANGLE={ang}"]
          for act, ang in itertools.product(("hbridge", "esc"), ("pwm", "ssi", "encoder"))}
BUILDS["esc490_encoder8000_nospeed"] = ["ACTUATOR=esc", "ESC_HZ=490", "ANGLE=encoder", "ENC_CPR=8000",
                                        "SPEED=none"]
BUILDS["esc490_encoder_index"] = ["ACTUATOR=esc", "ESC_HZ=490", "ANGLE=encoder", "ENC_CPR=4000",
                                  "ENC_INDEX=3999"]
BUILDS["hbridge_encoder_index"] = ["ANGLE=encoder", "ENC_CPR=2000", "ENC_INDEX=0"]


def _make(build: Path, *args: str) -> subprocess.CompletedProcess:
    return subprocess.run(["make", "-C", str(FW), f"BUILD={build}", *args], capture_output=True, text=True,
                          timeout=120)


@pytest.mark.parametrize("name", sorted(BUILDS))
def test_every_family_build_compiles(name: str, tmp_path: Path) -> None:
    r = _make(tmp_path, *BUILDS[name])
    assert r.returncode == 0, r.stdout + r.stderr
    elf = tmp_path / "aeropend.elf"
    size = subprocess.run(["avr-size", "-A", str(elf)], capture_output=True, text=True, check=True).stdout
    sec = {m[0]: int(m[1]) for m in re.findall(r"^(\.\w+)\s+(\d+)", size, flags=re.M)}
    assert 1000 < sec[".text"] + sec.get(".data", 0) < 32 * 1024, sec
    assert sec.get(".data", 0) + sec.get(".bss", 0) < 2048, sec
    nm = subprocess.run(["avr-nm", str(elf)], capture_output=True, text=True, check=True).stdout
    vectors = {int(v) for v in re.findall(r"^[0-9a-f]+ T __vector_(\d+)$", nm, flags=re.M)}
    want = {20, 25, 26}  # TIMER1_OVF, USART0_RX, USART0_UDRE
    if "encoder" in name:
        want |= {3, 4}  # INT2, INT3
    if "index" in name:
        want |= {1}  # INT0: the encoder's index
    assert want <= vectors, (name, sorted(vectors))
    assert (1 in vectors) == ("index" in name), "INT0 is the index's, in index builds only"
    assert ("ap_quad_step" in nm) == ("encoder" in name)
    assert (" ap_sample_pulse_pack" in nm) == name.startswith("esc")


@pytest.mark.parametrize("args, message", [
    (["ACTUATOR=esc", "ESC_HZ=40"], "ESC_HZ must be 50..490"),
    (["ACTUATOR=esc", "ESC_HZ=495"], "ESC_HZ must be 50..490"),
    (["ACTUATOR=esc", "ESC_HZ=50", "ESC_SILENCE_MS=80"], "ESC_SILENCE_MS + one frame must stay below 100 ms"),
    (["ACTUATOR=esc", "ESC_HZ=490", "ESC_MAX_US=2100"], "ESC pulse range must satisfy"),
    (["ANGLE=encoder", "ENC_CPR=70000"], "ENC_CPR must be 4..65535"),
    (["ACTUATOR=servo"], "ACTUATOR must be hbridge or esc"),
    (["ANGLE=encoder", "ENC_CPR=4000", "ENC_INDEX=4000"], "ENC_INDEX must be a count in 0..ENC_CPR-1"),
    (["ANGLE=pwm", "ENC_INDEX=10"], "ENC_INDEX needs ANGLE=encoder"),
])
def test_bad_build_choices_are_refused(args: list[str], message: str, tmp_path: Path) -> None:
    r = _make(tmp_path, *args)
    assert r.returncode != 0 and message in r.stdout + r.stderr, r.stdout + r.stderr


HOST_PROGRAM = r"""
#include <stdio.h>
#include "protocol.h"
static void hex(const char *tag, const uint8_t *p, size_t n)
{ printf("%s ", tag); for (size_t i = 0; i < n; i++) printf("%02x", p[i]); printf("\n"); }
int main(void)
{
    ap_hello_t h = {AP_ACT_ESC, AP_SENSOR_ENCODER, AP_CH_THETA | AP_CH_SPEED,
                    400, 1100, 1940, 1500, 57, 8000};
    uint8_t hb[AP_HELLO_LEN]; ap_hello_pack(&h, hb); hex("HELLO", hb, sizeof hb);
    ap_sample_t s = {65535, 4000000000u, AP_ABSENT_I16, AP_ABSENT_I16, 7999, AP_ABSENT_U32, 0, 0x81};
    uint8_t sb[AP_SAMPLE_PULSE_LEN]; ap_sample_pulse_pack(&s, 3001, sb); hex("SAMPLE", sb, sizeof sb);
    uint8_t pulse[3] = {AP_T_PULSE, 0xB9, 0x0B}, req[1] = {AP_T_HELLO_REQ}, bad[2] = {AP_T_HELLO_REQ, 0};
    ap_command_t c;
    int r = ap_command_parse(pulse, 3, &c);
    printf("PULSE %d %u\n", r, c.value);
    r = ap_command_parse(req, 1, &c);
    printf("REQ %d %d\n", r, ap_command_parse(bad, 2, &c));
    printf("QUAD");
    for (int i = 0; i < 16; i++) printf(" %d", ap_quad_step((uint8_t)(i >> 2), (uint8_t)(i & 3)));
    printf("\nBITS %u %u\n", AP_CH_INDEX, AP_FLAG_ANGLE_UNHOMED);
    printf("WRAP %u %u %u %u\n", ap_quad_wrap(3999, 1, 4000), ap_quad_wrap(0, -1, 4000),
           ap_quad_wrap(17, 1, 4000), ap_quad_wrap(17, 0, 4000));
    return 0;
}
"""


def test_c_and_python_codecs_agree_on_the_new_frames(tmp_path: Path) -> None:
    if shutil.which("gcc") is None:
        pytest.skip("needs gcc")
    src = tmp_path / "families.c"
    src.write_text(HOST_PROGRAM)
    exe = tmp_path / "families"
    subprocess.run(["gcc", "-std=c99", "-Wall", "-Wextra", "-Werror", "-I", str(FW / "src"), "-o", str(exe),
                    str(src), str(FW / "src" / "protocol.c")], check=True, capture_output=True, text=True)
    out = {ln.split()[0]: ln.split()[1:] for ln in subprocess.run([str(exe)], capture_output=True, text=True,
                                                                  check=True).stdout.splitlines()}
    hello = HelloFrame(2, 2, 3, 0x0C, 400, 1100, 1940, 1500, 57, 8000)
    assert out["HELLO"][0] == hello.payload().hex()
    assert parse_payload(bytes.fromhex(out["HELLO"][0])) == hello
    sample = PulseSampleFrame(65535, 4_000_000_000, ABSENT_I16, ABSENT_I16, 7999, ABSENT_U32, 0, 0x81,
                              pulse=3001)
    assert out["SAMPLE"][0] == sample.payload().hex()
    assert parse_payload(bytes.fromhex(out["SAMPLE"][0])) == sample
    assert Pulse(0x0BB9).payload() == bytes([0x14, 0xB9, 0x0B]) and out["PULSE"] == ["0", str(0x0BB9)]
    assert HelloRequest().payload() == b"\x15" and out["REQ"] == ["0", "-3"]  # -3: AP_E_LENGTH
    # x4 decoding, independently: the Gray sequence 00 -> A -> AB -> B (A leads B) counts up
    gray = [0b00, 0b01, 0b11, 0b10]
    want = []
    for i in range(16):
        prev, now = i >> 2, i & 3
        if prev == now:
            want.append(0)
        elif gray[(gray.index(prev) + 1) % 4] == now:
            want.append(1)
        elif gray[(gray.index(prev) - 1) % 4] == now:
            want.append(-1)
        else:
            want.append(2)  # both lines changed: invalid
    assert [int(v) for v in out["QUAD"]] == want
    assert out["WRAP"] == ["0", "3999", "18", "17"]
    assert out["BITS"] == [str(CH_INDEX), str(FLAG_ANGLE_UNHOMED)]
