"""Build the ATmega2560 firmware with avr-gcc (``make -C firmware``) and check the ELF.

Checks: the build is warning-free (-Werror), flash and RAM use fit the ATmega2560 with a wide
margin, and the interrupt vectors the design relies on are implemented (not the default
handler): TIMER1_OVF (20), USART0_RX (25), USART0_UDRE (26), ADC (29), TIMER4_CAPT (41),
TIMER4_OVF (45).
"""

from __future__ import annotations

import re
import shutil
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
FLASH_BYTES = 256 * 1024
SRAM_BYTES = 8 * 1024
VECTORS = {20: "TIMER1_OVF", 25: "USART0_RX", 26: "USART0_UDRE", 29: "ADC", 41: "TIMER4_CAPT",
           45: "TIMER4_OVF"}

pytestmark = pytest.mark.skipif(
    shutil.which("avr-gcc") is None or shutil.which("make") is None,
    reason="needs avr-gcc + make (scripts/setup_env.sh installs gcc-avr/avr-libc as root)",
)


@pytest.fixture(scope="module")
def elf(tmp_path_factory: pytest.TempPathFactory) -> Path:
    build = tmp_path_factory.mktemp("fwbuild")
    r = subprocess.run(["make", "-C", str(ROOT / "firmware"), f"BUILD={build}"], capture_output=True,
                       text=True, timeout=120)
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
