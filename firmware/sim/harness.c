/*
 * simavr harness: runs the real aeropend firmware ELF on an emulated ATmega2560 at 16 MHz,
 * exposes USART0 as a pty (simavr's uart_pty part) and drives the ADC inputs.
 *
 *   build/harness firmware.elf [cycles [A0_mV A1_mV A2_mV A3_mV]]
 *
 * Prints "PTY <slave path>" on stdout once the UART is connected, then runs `cycles` CPU
 * cycles of 1/16 us (0 = until SIGTERM / SIGINT) and prints "CYCLES <n>" on exit. AVcc = 5 V. The firmware idles in SLEEP_MODE_IDLE between interrupts, so simavr's raw sleep
 * callback paces the simulation to wall-clock time (when the host is fast enough).
 *
 * Not emulated here: the IR sensor edges on ICP4 (simavr 1.6 has no input-capture pin
 * stimulus), PWM output waveform checking, the AS5040 and the motor shield. The capture logic
 * is covered by the host unit test firmware/test/test_codec.c.
 */
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "avr_adc.h"
#include "sim_avr.h"
#include "sim_elf.h"
#include "uart_pty.h"

static volatile sig_atomic_t stop;
static void on_signal(int sig) { (void)sig; stop = 1; }

int main(int argc, char **argv)
{
    if (argc < 2) {
        fprintf(stderr, "usage: %s firmware.elf [cycles [A0_mV A1_mV A2_mV A3_mV]]\n", argv[0]);
        return 2;
    }
    elf_firmware_t fw;
    memset(&fw, 0, sizeof fw);
    if (elf_read_firmware(argv[1], &fw) != 0) {
        fprintf(stderr, "cannot read firmware %s\n", argv[1]);
        return 2;
    }
    avr_t *avr = avr_make_mcu_by_name("atmega2560");
    if (!avr) {
        fprintf(stderr, "simavr has no atmega2560 core\n");
        return 2;
    }
    avr_init(avr);
    avr->frequency = 16000000;
    avr->avcc = 5000; /* simavr's default is 3.3 V; the Mega runs at 5 V */
    avr->vcc = 5000;
    avr_load_firmware(avr, &fw);
    avr->log = LOG_ERROR;

    uart_pty_t pty;
    memset(&pty, 0, sizeof pty);
    uart_pty_init(avr, &pty);
    uart_pty_connect(&pty, '0');

    unsigned long long max_cycles = argc > 2 ? strtoull(argv[2], NULL, 10) : 0;
    int mv[4] = {500, 1000, 2500, 1250};
    for (int i = 0; i < 4 && 3 + i < argc; i++)
        mv[i] = atoi(argv[3 + i]);
    for (int i = 0; i < 4; i++)
        avr_raise_irq(avr_io_getirq(avr, AVR_IOCTL_ADC_GETIRQ, ADC_IRQ_ADC0 + i), (uint32_t)mv[i]);

    signal(SIGTERM, on_signal);
    signal(SIGINT, on_signal);
    printf("PTY %s\n", pty.port[0].slavename);
    fflush(stdout);

    int state = cpu_Running;
    while (!stop && state != cpu_Done && state != cpu_Crashed &&
           (max_cycles == 0 || avr->cycle < max_cycles))
        state = avr_run(avr);
    printf("CYCLES %llu\n", (unsigned long long)avr->cycle);
    fflush(stdout);
    fprintf(stderr, "harness: stopped (cpu state %d, %llu cycles)\n", state,
            (unsigned long long)avr->cycle);
    /* uart_pty_stop() can block forever joining its pty thread (simavr 1.6): just exit. */
    _exit(state == cpu_Crashed ? 1 : 0);
}
