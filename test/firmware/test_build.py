"""Build the ATmega2560 firmware with avr-gcc (``make -C firmware``) and check the ELF.

Both angle interfaces are built: ``ANGLE=pwm`` (default: AS5040 PWM -> RC -> ADC2) and
``ANGLE=ssi`` (AS5040 SSI read-out, bit-banged on PA0..PA2), plus the thesis' 22-clock SSI
variant. Checks: the build is warning-free (-Werror), flash and RAM use fit the ATmega2560
with a wide margin, the interrupt vectors the design relies on are implemented (not the
default handler): TIMER1_OVF (20), USART0_RX (25), USART0_UDRE (26), ADC (29), TIMER4_CAPT
(41), TIMER4_OVF (45), and the SSI word decoder is linked into the SSI build only.
"""

from __future__ import annotations

import re
import shutil
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
FLASH_BYTES = 256 * 1024
SRAM_BYTES = 8 * 1024
VECTORS = {20: "TIMER1_OVF", 25: "USART0_RX", 26: "USART0_UDRE", 29: "ADC", 41: "TIMER4_CAPT",
           45: "TIMER4_OVF"}

pytestmark = pytest.mark.skipif(
    shutil.which("avr-gcc") is None or shutil.which("make") is None,
    reason="needs avr-gcc + make (scripts/setup_env.sh installs gcc-avr/avr-libc as root)",
)


VARIANTS = {"pwm": ["ANGLE=pwm"], "ssi": ["ANGLE=ssi"],
            "ssi22": ["ANGLE=ssi", "EXTRA_CFLAGS=-DSSI_CLOCKS=22"]}


@pytest.fixture(scope="module", params=sorted(VARIANTS))
def elf(request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory) -> Path:
    build = tmp_path_factory.mktemp(f"fwbuild_{request.param}")
    r = subprocess.run(["make", "-C", str(ROOT / "firmware"), f"BUILD={build}", *VARIANTS[request.param]],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stdout + r.stderr
    out = build / "aeropend.elf"
    assert out.is_file() and (build / "aeropend.hex").is_file()
    return out


def test_firmware_size_fits(elf: Path) -> None:
    r = subprocess.run(["avr-size", "-A", str(elf)], capture_output=True, text=True, check=True)
    sec = {m[0]: int(m[1]) for m in re.findall(r"^(\.\w+)\s+(\d+)", r.stdout, flags=re.M)}
    flash = sec[".text"] + sec.get(".data", 0)
    ram = sec.get(".data", 0) + sec.get(".bss", 0)
    assert 1000 < flash < FLASH_BYTES // 8, sec  # a few kB, far below 256 KiB
    assert ram < SRAM_BYTES // 4, sec  # rings + decoder; leaves > 6 KiB for the stack


def test_firmware_implements_its_interrupts(elf: Path) -> None:
    r = subprocess.run(["avr-nm", str(elf)], capture_output=True, text=True, check=True)
    strong = {int(m) for m in re.findall(r"^[0-9a-f]+ T __vector_(\d+)$", r.stdout, flags=re.M)}
    missing = {n: name for n, name in VECTORS.items() if n not in strong}
    assert not missing, f"interrupt handlers missing: {missing}"


def test_ssi_decoder_only_in_the_ssi_build(elf: Path) -> None:
    r = subprocess.run(["avr-nm", str(elf)], capture_output=True, text=True, check=True)
    has_ssi = " ap_as5040_decode" in r.stdout
    assert has_ssi == ("ssi" in elf.parent.name), (elf.parent.name, has_ssi)


def test_unknown_angle_interface_is_rejected(tmp_path: Path) -> None:
    r = subprocess.run(["make", "-C", str(ROOT / "firmware"), f"BUILD={tmp_path}", "ANGLE=spi"],
                       capture_output=True, text=True, timeout=60)
    assert r.returncode != 0 and "ANGLE must be pwm or ssi" in r.stderr


def test_ssi_clock_count_is_bounded(tmp_path: Path) -> None:
    """The AS5040 word has 16 bits: fewer clocks would truncate it (build error, not a bad angle)."""
    r = subprocess.run(["make", "-C", str(ROOT / "firmware"), f"BUILD={tmp_path}", "ANGLE=ssi",
                        "EXTRA_CFLAGS=-DSSI_CLOCKS=15"], capture_output=True, text=True, timeout=60)
    assert r.returncode != 0 and "SSI_CLOCKS must be 16..22" in r.stdout + r.stderr
