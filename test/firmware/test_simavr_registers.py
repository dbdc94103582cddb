"""Peripheral set-up of the *production* firmware builds, decoded from the registers on simavr.

simavr 1.6 does not emulate Timer1's phase-correct PWM on the ATmega2560 (the timing tests run
the ``-DSIMAVR_TIMER1`` emulator build, fast PWM with TOP = ICR1 = 509). This test runs the
unmodified production builds (``ANGLE=pwm`` and ``ANGLE=ssi``) in the harness for 0.1 s, dumps
the configuration registers as the firmware wrote them (``harness -r``) and decodes them with the
ATmega2560 datasheet tables: Timer1 phase-correct 8-bit PWM at clk/64 (490.2 Hz, TOV1 every
510 ticks = 2.040 ms), non-inverting OC1A on PB5 with the shield's DIR/BRAKE pins; Timer4 normal
mode at 4 µs with rising-edge input capture and noise canceller; USART0 8N1 at exactly
500 000 baud; ADC at 125 kHz; watchdog 120 ms; the SSI pins idle high. The emulator build must
give the same TOV1 period with its substitute mode. Constants are compared with the ones the
host side uses (``protocol.BAUD``, ``protocol.TIMER4_TICK_S``).
"""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import pytest

from aeropend_bridge.protocol import BAUD, TIMER4_TICK_S

ROOT = Path(__file__).resolve().parents[2]
FW = ROOT / "firmware"
F_CPU = 16_000_000
PRESCALER = {0: 0, 1: 1, 2: 8, 3: 64, 4: 256, 5: 1024}  # CSn2:0 of Timer1/3/4/5

pytestmark = [
    # one worker builds and runs the emulated firmware once (its module fixtures were made again on
    # every worker that got one of its tests)
    pytest.mark.xdist_group("test_simavr_registers"),
    pytest.mark.timeout(60),
    pytest.mark.skipif(
        shutil.which("avr-gcc") is None or not Path("/usr/include/simavr/sim_avr.h").is_file(),
        reason="needs avr-gcc + libsimavr-dev/libsimavrparts1 (scripts/setup_env.sh installs them as root)"),
]


def _regs(build: Path, *make_args: str) -> dict[str, int]:
    for args in (["all", *make_args], ["harness"]):
        r = subprocess.run(["make", "-C", str(FW), f"BUILD={build}", *args], capture_output=True, text=True,
                           timeout=120)
        assert r.returncode == 0, r.stdout + r.stderr
    # 0.1 s: hw_init done, before the production build's first (mis-emulated) TOV1 at 4.2 M cycles
    r = subprocess.run([str(build / "harness"), str(build / "aeropend.elf"), str(F_CPU // 10), "-r"],
                       capture_output=True, text=True, timeout=30)
    assert r.returncode == 0, r.stderr
    return {ln.split()[1]: int(ln.split()[2]) for ln in r.stdout.splitlines() if ln.startswith("REG ")}


@pytest.fixture(scope="module")
def prod(tmp_path_factory: pytest.TempPathFactory) -> dict[str, dict[str, int]]:
    return {a: _regs(tmp_path_factory.mktemp(f"reg_{a}"), f"ANGLE={a}") for a in ("pwm", "ssi")}


def _bits(v: int, hi: int, lo: int) -> int:
    return (v >> lo) & ((1 << (hi - lo + 1)) - 1)


def _timer1(r: dict[str, int]) -> tuple[int, int, int]:
    """(WGM1 mode 0..15, prescaler, COM1A) from TCCR1A/B (datasheet Table 17-2)."""
    wgm = _bits(r["TCCR1A"], 1, 0) | (_bits(r["TCCR1B"], 4, 3) << 2)
    return wgm, PRESCALER[_bits(r["TCCR1B"], 2, 0)], _bits(r["TCCR1A"], 7, 6)


@pytest.mark.parametrize("angle", ["pwm", "ssi"])
def test_timer1_phase_correct_pwm_490hz(prod: dict, angle: str) -> None:
    r = prod[angle]
    wgm, n, com1a = _timer1(r)
    assert wgm == 1, "WGM1 = 0b0001: PWM, phase correct, 8-bit (TOP = 0xFF)"
    top = 0xFF
    f_pwm = F_CPU / (2 * n * top)  # datasheet: f = f_clk / (2 N TOP)
    tov1_us = 2 * top * n / F_CPU * 1e6  # TOV1 at BOTTOM: one up-down cycle
    assert f_pwm == pytest.approx(490.196, abs=1e-3) and tov1_us == pytest.approx(2040.0)
    assert com1a == 0b10, "non-inverting PWM on OC1A"
    assert r["TIMSK1"] & 0x01, "TOIE1: the sample tick"
    # OC1A = PB5 (D11, shield channel B PWM) output; DIR B = PB7 (D13) high; BRAKE B = PH5 (D8) low
    assert r["DDRB"] & (1 << 5) and r["DDRB"] & (1 << 7) and r["PORTB"] & (1 << 7)
    assert r["DDRH"] & (1 << 5) and not r["PORTH"] & (1 << 5)


@pytest.mark.slow
def test_emulator_build_keeps_the_tov1_period(tmp_path: Path, prod: dict) -> None:
    emu = _regs(tmp_path, "ANGLE=pwm", "EXTRA_CFLAGS=-DSIMAVR_TIMER1")
    wgm, n, com1a = _timer1(emu)
    icr1 = emu["ICR1L"] | emu["ICR1H"] << 8
    assert wgm == 14 and icr1 == 509 and com1a == 0b10  # fast PWM, TOP = ICR1
    assert (icr1 + 1) * n / F_CPU * 1e6 == pytest.approx(2040.0)
    # Everything but Timer1 is configured identically. The emulator build is already sampling
    # (the production build's mis-emulated TOV1 has not come yet), so run-time bits are masked:
    # ADMUX/ADCSRB (channel chain), ADSC + ADIF, UDRIE0, the UCSR0A status flags, sleep enable.
    dynamic = {"ADCSRA": 0x50, "UCSR0B": 0x20, "UCSR0A": 0xFD, "SMCR": 0x01}
    diff = {k for k in emu if (emu[k] ^ prod["pwm"][k]) & ~dynamic.get(k, 0)}
    assert diff <= {"TCCR1A", "TCCR1B", "ICR1L", "ICR1H", "ADMUX", "ADCSRB"}, diff


@pytest.mark.parametrize("angle", ["pwm", "ssi"])
def test_timer4_capture_usart_adc_watchdog(prod: dict, angle: str) -> None:
    r = prod[angle]
    # Timer4: normal mode, clk/64 = 4 µs ticks, input capture on the rising edge, noise canceller
    wgm4 = _bits(r["TCCR4A"], 1, 0) | (_bits(r["TCCR4B"], 4, 3) << 2)
    assert wgm4 == 0
    assert PRESCALER[_bits(r["TCCR4B"], 2, 0)] / F_CPU == pytest.approx(TIMER4_TICK_S)
    assert r["TCCR4B"] & 0x40 and r["TCCR4B"] & 0x80, "ICES4 rising edge, ICNC4 noise canceller"
    assert r["TIMSK4"] == 0x21, "ICIE4 + TOIE4"
    assert not r["DDRL"] & 0x01, "ICP4 = PL0 is an input"
    # USART0: U2X, UBRR = 3 -> exactly the host's baud rate, 8N1, RX/TX + RX interrupt
    ubrr = r["UBRR0L"] | r["UBRR0H"] << 8
    assert r["UCSR0A"] & 0x02
    baud = F_CPU / (8 * (ubrr + 1))
    assert baud == BAUD and ubrr == 3
    assert _bits(r["UCSR0C"], 2, 1) == 0b11 and not r["UCSR0B"] & 0x04, "8 data bits"
    assert _bits(r["UCSR0C"], 5, 4) == 0 and not r["UCSR0C"] & 0x08, "no parity, 1 stop bit"
    assert r["UCSR0B"] & 0x98 == 0x98, "RXCIE0, RXEN0, TXEN0"
    # ADC: enabled, interrupt, clk/128 = 125 kHz (50..200 kHz for full resolution); A0..A3 digital off
    assert r["ADCSRA"] & 0x88 == 0x88 and F_CPU / 2 ** _bits(r["ADCSRA"], 2, 0) == 125_000
    assert r["DIDR0"] == 0x0F
    # Watchdog: system reset mode (WDE), WDP = 0b0011 -> 16K cycles of the 128 kHz oscillator
    wdp = _bits(r["WDTCSR"], 2, 0) | (_bits(r["WDTCSR"], 5, 5) << 3)
    assert r["WDTCSR"] & 0x08 and 2048 * 2 ** wdp / 128_000 == pytest.approx(0.128)


def test_ssi_pins_idle_high_only_in_the_ssi_build(prod: dict) -> None:
    # CSn = PA0, CLK = PA1 outputs idling high, DO = PA2 input with pull-up
    assert prod["ssi"]["DDRA"] & 0x07 == 0x03 and prod["ssi"]["PORTA"] & 0x07 == 0x07
    assert prod["pwm"]["DDRA"] == 0 and prod["pwm"]["PORTA"] == 0
