/*
 * simavr harness: runs the real aeropend firmware ELF on an emulated ATmega2560 at 16 MHz,
 * exposes USART0 as a pty (its own single-threaded link, below), drives the ADC inputs and, from
 * an event file, the IR propeller sensor on ICP4 and an AS5040 SSI slave on the GPIO pins.
 *
 *   build/harness firmware.elf [cycles [A0_mV A1_mV A2_mV A3_mV]] [-e events.txt] [-r]
 *
 * Prints "PTY <path>" on stdout once the UART is connected (a symlink to the pty of this process's
 * own, removed on exit; see link_open), then runs `cycles` CPU cycles of 1/16 us (0 = until
 * SIGTERM / SIGINT) and prints "CYCLES <n>" on exit; with an
 * event file also "T4START <cycle>" (stderr) and "IREDGES <n>" / "SSIREADS <n> <bad>" /
 * "SSITIMING clkfe_min <ns> half_min <ns> read_min <ns> read_max <ns> rises <min> <max>" (stdout)
 * on exit. AVcc = 5 V. The firmware idles in SLEEP_MODE_IDLE between interrupts, so simavr's
 * raw sleep callback paces the simulation to wall-clock time (when the host is fast enough).
 *
 * Host link: USART0 <-> a pty, served in the emulation thread itself (link_* below), not by
 * simavr's uart_pty part, whose own thread calls into the UART (avr_raise_irq ->
 * avr_uart_irq_input -> avr_cycle_timer_register) while avr_run() edits the same cycle-timer list
 * (simavr's IRQs and timers are single-threaded by design). The host's bytes enter the UART at
 * most one per byte time (22 us at 500 kbaud, 8N1 + simavr's parity slot), once the firmware has
 * enabled its receiver (earlier bytes would be dropped by the UART: an RX error in the firmware's
 * count); the MCU's bytes go to a 64 KiB buffer written to the pty without blocking. A real
 * USB-serial link does not lose bytes because the host's scheduler is busy, so the emulation
 * waits (wall-clock time passes, MCU time does not) while the host is behind by more than
 * LINK_OUT_HIGH bytes beyond LINK_PTY_MAX unread in the pty (~0.3 s of 490 Hz frames): the
 * firmware's stream reaches the host complete and the host's view of MCU time stays recent
 * (bench/repro/simavr_pty_overflow.py); with no host reading, the emulation waits. On exit the
 * harness waits until the host has read every byte (at most 10 s; "LINKLOST <n>" on stdout if it
 * did not). The pty is announced by a name of this process's own (link_open): a host that
 * reconnected by /dev/pts/N after the harness ended read the next harness's frames
 * (bench/repro/simavr_pty_reuse.py).
 *
 * -r prints "REG <name> <value>" for the peripheral configuration registers on exit (data-space
 * values as the firmware wrote them), so a test can decode the production build's Timer1 set-up
 * that simavr does not emulate.
 *
 * Event file, one event per line, times in microseconds (fractions allowed, 1/16 us = one CPU
 * cycle) after the firmware starts Timer4 (its write of a non-zero clock select to TCCR4B), so
 * the Timer4 tick (4 us) and overflow (65536 ticks = 262144 us) instants are known exactly:
 *   ir  <t_us> <level>   set the IR sensor output on ICP4 = PL0 (Mega D49) to 0/1; the pin
 *                        IRQ drives simavr's Timer4 input-capture unit (TIMER_IRQ_IN_ICP
 *                        path of avr_timer.c, edge chosen by ICES4)
 *   ssi <t_us> <word>    from t_us on, the AS5040 shifts out this 16-bit SSI word (D9..D0,
 *                        OCF, COF, LIN, MagINC, MagDEC, even parity; MSB first), hex or dec
 * Lines are sorted by time per kind; '#' starts a comment.
 *
 * AS5040 SSI slave (datasheet "Synchronous Serial Interface"): CSn = PA0 (D22) and CLK = PA1
 * (D23) are firmware outputs, DO = PA2 (D24) is driven here. CSn low: DO goes high; the first
 * falling CLK edge latches the word; each following rising CLK edge shifts out one bit, MSB
 * first; after 16 bits DO reads 0 (the daisy-chain input DI tied low); CSn high: DO tri-state,
 * read as 1 (pull-up). The pin timing is measured (SSITIMING) for the test to check against the
 * datasheet: t_CLKFE (CSn low to first CLK fall) >= 500 ns, CLK half period >= 500 ns (1 MHz).
 *
 * ESC output and encoder input (issue 61):
 *   -p pulses.txt   logs every level change of the ESC signal pin OC3A = PE3 (Mega D5) as
 *                   "P <cycle> <level>" and every frame delimiter (0x00) the UART receives from
 *                   the host as "RX <cycle>", in CPU cycles from reset (16 per us); also
 *                   "T1START <cycle>" (the firmware's Timer1 start: sample t_us is counted from it)
 *   enccpr <cpr>                        (event file) counts per revolution of the emulated encoder
 *   enc <t0_us> <t1_us> <th0> <A> <W>   (event file) from t0 to t1 (us after the Timer1 start) the
 *                        rod angle is th0 + A*sin(W*(t - t0)) [rad, rad/s]; it holds its last value
 *                        between segments. Every 1 us the harness moves the quadrature lines A =
 *                        PD2 (INT2, D19) and B = PD3 (INT3, D18) one x4 step towards
 *                        floor(theta * cpr / 2pi) (A leads B for a rising count), and prints
 *                        "ENC <steps> <final count> <max lag counts>" on exit.
 *   encindex <N>                        (event file) the encoder's gated index Z on PD0 (INT0, D21):
 *                        high while the disk's count (mod cpr) is N; "INDEX <rising edges>" on exit
 *   encslip <t_us> <n>                  (event file) the first n counts the disk moves from t_us on
 *                        do not reach the lines A/B (a signal drop-out: they stay as they were;
 *                        n = 4, one line period, leaves no impossible transition to see)
 *
 * Closed-loop plant coupling (issue 61):
 *   -P SOCKET [-Q US]  connects to a plant process listening on the Unix stream socket SOCKET
 *                   (aeropend_bridge.simavr_plant). Every US microseconds of MCU time (default 1000;
 *                   at k * US from reset, from the firmware's Timer1 start on; the rod rests
 *                   before) the emulation thread sends the record {double t [s] since reset,
 *                   double pulse [s]} (native byte order, 16 bytes): the width of the last complete
 *                   high pulse on OC3A = PE3, measured from its edges (0 before the first one), and
 *                   blocks until it reads back {double theta [rad]}: the rod angle at t. The encoder
 *                   emulation then follows that angle (one x4 step per us towards
 *                   floor(theta * cpr / 2pi + M)) instead of the event file's enc segments. MCU time
 *                   stands still while the plant computes. On exit "PLANT <exchanges> <max lag
 *                   counts>" on stdout; a plant that closes the socket ends the run ("PLANTLOST").
 *   -H US           host lock-step: once the host has answered each of the MCU's last LINK_HOLD_STREAK
 *                   sample frames (a DUTY or PULSE frame from the host after each), MCU time stands
 *                   still US microseconds after the MCU's next sample frame until the host's answer
 *                   has come (at most LINK_HOLD_MAX_US of wall-clock time: a host that stopped
 *                   answering lets the MCU run on). With US shorter than the sample period less the
 *                   frame's and the answer's bytes, every answer reaches the firmware before its
 *                   next tick, as from a host that is never late; without -H the answers come when
 *                   the host's scheduler delivers them. On exit "HOLDS <holds> <timeouts>" on stdout.
 *   -M COUNTS       where the emulated encoder's disk is mounted (default 0: count k spans
 *                   [k, k + 1) q from the rod's rest, the count floors the angle; 0.5: count k is
 *                   centred on k q, the count rounds it as aeropend's quantisation effect does)
 *
 * Not emulated: the analogue front end, the motor shield, the ESC itself.
 */
#include <errno.h>
#include <fcntl.h>
#include <math.h>
#include <pty.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/ioctl.h>
#include <sys/socket.h>
#include <sys/un.h>
#include <termios.h>
#include <time.h>
#include <unistd.h>

#include "avr_adc.h"
#include "avr_ioport.h"
#include "avr_uart.h"
#include "sim_avr.h"
#include "sim_elf.h"
#include "sim_io.h"

/* Host link (see the header comment): MCU -> host buffer, its flow-control mark, host -> MCU
 * pacing (one byte per UART byte time) and how often the pty is read and written [cycles]. */
#define LINK_OUT_SIZE 65536
#define LINK_OUT_HIGH 2048  /* ~0.17 s of 490 Hz sample frames */
#define LINK_PTY_MAX 2048   /* bytes left unread by the host in the pty, at most */
#define UCSR0B_ADDR 0xC1
#define RXEN0_BIT 4
#define LINK_BYTE_CYCLES 352 /* 22 us: simavr's USART byte time at 500 kbaud */
#define LINK_IO_CYCLES 1408  /* 88 us */
#define LINK_HOLD_MAX_US 10000 /* -H: the longest MCU time stands still for one answer [us, wall] */
#define LINK_HOLD_STREAK 8     /* -H: sample frames answered in a row before MCU time waits for answers */
/* frame types (firmware/src/protocol.h): the byte after a frame's COBS code byte */
#define LINK_T_SAMPLE 0x01
#define LINK_T_SAMPLE_PULSE 0x04
#define LINK_T_DUTY 0x10
#define LINK_T_PULSE 0x14

typedef struct {
    int fd;    /* pty master, non-blocking */
    int slave; /* kept open: the host's unread bytes are counted on it (FIONREAD) */
    char path[256]; /* the name announced to the host: a symlink to slavename, removed on exit */
    char slavename[64];
    uint8_t out[LINK_OUT_SIZE]; /* ring: MCU bytes not yet written to the pty */
    size_t out_head, out_len;
    unsigned long out_dropped;  /* bytes the ring could not take (never expected) */
    uint8_t in[512];            /* host bytes read from the pty, not yet given to the UART */
    size_t in_len, in_done;
    /* -H host lock-step: hold_cycles (0: off); the byte position in the current MCU / host frame and
     * its type; a host DUTY/PULSE frame read since the MCU's last sample frame; a sample frame
     * ended (set by the UART callback, handled in link_service); the armed hold and its cycle */
    avr_cycle_count_t hold_cycles, hold_at;
    unsigned out_pos, in_pos;
    uint8_t out_type, in_type;
    int answered, sample_out, hold_armed, streak;
    unsigned long holds, hold_timeouts;
    int xoff;                   /* the UART's input FIFO is full */
    avr_irq_t *rx;              /* UART_IRQ_INPUT */
    avr_cycle_count_t next_feed, next_io;
} link_t;

#define TCCR4B_ADDR 0xA1 /* data-space address on the ATmega2560 */
#define TCCR1B_ADDR 0x81
#define MAX_SEGMENTS 64
#define MAX_EVENTS 20000

typedef struct {
    double t_us; /* fractional: 1/16 us = one CPU cycle */
    unsigned value;
} event_t;

typedef struct {
    avr_t *avr;
    event_t *ir, *ssi;
    int n_ir, n_ssi, i_ir, i_ssi;
    avr_cycle_count_t t4_start; /* 0 until Timer4 starts */
    avr_irq_t *icp, *dout;
    /* SSI slave state */
    unsigned cs, clk, latched, bit, word;
    unsigned reads, bad_reads;
    unsigned long ir_edges;
    /* SSI timing seen on the pins [cycles]: CSn fall, last CLK edge, extremes */
    avr_cycle_count_t cs_fall, clk_edge, min_clkfe, min_half, min_read, max_read;
    unsigned rises, min_rises, max_rises;
    /* ESC pulse log and encoder emulation */
    FILE *plog;
    avr_cycle_count_t t1_start;
    struct { double t0, t1, th0, a, w; } seg[MAX_SEGMENTS];
    int n_seg;
    long cpr, enc_count, enc_steps, enc_max_lag;
    avr_irq_t *enc_a, *enc_b;
    /* index Z on PD0 (-1: none), slip: counts the lines fall behind the disk from slip_t on */
    long enc_index, enc_slip, slip_n, index_edges;
    double slip_t, enc_mount;
    avr_irq_t *enc_z;
    /* closed-loop plant (-P): socket, exchange interval [cycles], the pulse seen on the pin */
    int plant_fd;
    avr_cycle_count_t plant_every, pulse_rise, pulse_width;
    unsigned pulse_level;
    double plant_theta;
    unsigned long plant_exchanges;
} sim_t;

/* ATmega2560 data-space addresses (avr-libc iomxx0_1.h). */
static const struct { const char *name; uint16_t addr; } REGS[] = {
    {"TCCR1A", 0x80}, {"TCCR1B", 0x81}, {"OCR1AL", 0x88}, {"OCR1AH", 0x89}, {"ICR1L", 0x86},
    {"ICR1H", 0x87}, {"TIMSK1", 0x6F}, {"TCCR4A", 0xA0}, {"TCCR4B", 0xA1}, {"TIMSK4", 0x72},
    {"UCSR0A", 0xC0}, {"UCSR0B", 0xC1}, {"UCSR0C", 0xC2}, {"UBRR0L", 0xC4}, {"UBRR0H", 0xC5},
    {"ADMUX", 0x7C}, {"ADCSRA", 0x7A}, {"ADCSRB", 0x7B}, {"DIDR0", 0x7E}, {"DDRA", 0x21},
    {"PORTA", 0x22}, {"DDRB", 0x24}, {"PORTB", 0x25}, {"DDRH", 0x101}, {"PORTH", 0x102},
    {"DDRL", 0x10A}, {"PORTL", 0x10B}, {"WDTCSR", 0x60}, {"SMCR", 0x53},
};

static volatile sig_atomic_t stop;
static void on_signal(int sig) { (void)sig; stop = 1; }

static avr_cycle_count_t us_to_cycles(const sim_t *s, double us)
{
    return s->t4_start + (avr_cycle_count_t)(us * (s->avr->frequency / 1e6) + 0.5);
}

static void set_dout(sim_t *s, unsigned level)
{
    /* An input pin with PORT = 1 (pull-up) is re-raised to 1 by simavr on every PORT write
     * unless an "external" level is declared: declare the driven level, then raise it. */
    avr_ioport_external_t ext = {.name = 'A', .mask = 1u << 2, .value = (level ? 1u : 0u) << 2};
    avr_ioctl(s->avr, AVR_IOCTL_IOPORT_SET_EXTERNAL('A'), &ext);
    avr_raise_irq(s->dout, level ? 1 : 0);
}

static avr_cycle_count_t ir_timer(avr_t *avr, avr_cycle_count_t when, void *param)
{
    (void)avr; (void)when;
    sim_t *s = param;
    while (s->i_ir < s->n_ir && us_to_cycles(s, s->ir[s->i_ir].t_us) <= s->avr->cycle) {
        unsigned v = s->ir[s->i_ir].value ? 1 : 0;
        if (v && !s->icp->value)
            s->ir_edges++;
        avr_raise_irq(s->icp, v);
        s->i_ir++;
    }
    return s->i_ir < s->n_ir ? us_to_cycles(s, s->ir[s->i_ir].t_us) : 0;
}

static void on_tccr4b(struct avr_irq_t *irq, uint32_t value, void *param)
{
    (void)irq;
    sim_t *s = param;
    if (s->t4_start || (value & 0x07) == 0)
        return;
    s->t4_start = s->avr->cycle;
    fprintf(stderr, "T4START %llu\n", (unsigned long long)s->t4_start);
    if (s->n_ir) {
        avr_cycle_count_t first = us_to_cycles(s, s->ir[0].t_us);
        avr_cycle_timer_register(s->avr, first > s->avr->cycle ? first - s->avr->cycle : 1, ir_timer, s);
    }
}

static unsigned ssi_word_now(sim_t *s)
{
    if (!s->t4_start)
        return 0; /* not started: OCF = 0, the firmware must reject it */
    while (s->i_ssi + 1 < s->n_ssi && us_to_cycles(s, s->ssi[s->i_ssi + 1].t_us) <= s->avr->cycle)
        s->i_ssi++;
    if (s->n_ssi == 0 || us_to_cycles(s, s->ssi[s->i_ssi].t_us) > s->avr->cycle)
        return 0;
    return s->ssi[s->i_ssi].value & 0xFFFFu;
}

static void on_csn(struct avr_irq_t *irq, uint32_t value, void *param)
{
    (void)irq;
    sim_t *s = param;
    value = value ? 1 : 0;
    if (value == s->cs)
        return;
    s->cs = value;
    s->latched = 0;
    avr_cycle_count_t now = s->avr->cycle;
    if (!value) {
        s->cs_fall = now;
        s->rises = 0;
    } else if (s->cs_fall) {
        if (now - s->cs_fall > s->max_read)
            s->max_read = now - s->cs_fall;
        if (now - s->cs_fall < s->min_read)
            s->min_read = now - s->cs_fall;
        if (s->rises < s->min_rises)
            s->min_rises = s->rises;
        if (s->rises > s->max_rises)
            s->max_rises = s->rises;
    }
    set_dout(s, 1); /* CSn low: DO driven high; CSn high: tri-state, pulled up */
}

static void on_clk(struct avr_irq_t *irq, uint32_t value, void *param)
{
    (void)irq;
    sim_t *s = param;
    value = value ? 1 : 0;
    if (value == s->clk)
        return;
    s->clk = value;
    if (s->cs)
        return;
    avr_cycle_count_t now = s->avr->cycle;
    if (s->latched && now - s->clk_edge < s->min_half)
        s->min_half = now - s->clk_edge;
    s->clk_edge = now;
    if (value)
        s->rises++;
    if (!value && !s->latched) { /* first falling edge: latch */
        if (now - s->cs_fall < s->min_clkfe)
            s->min_clkfe = now - s->cs_fall;
        s->latched = 1;
        s->bit = 0;
        s->word = ssi_word_now(s);
        s->reads++;
        unsigned p = 0;
        for (unsigned w = s->word; w; w >>= 1)
            p ^= w & 1u;
        if (p || !((s->word >> 5) & 1u) || ((s->word >> 4) & 1u) || (s->word & 6u) == 6u)
            s->bad_reads++; /* parity, OCF = 0, COF = 1, MagINC = MagDEC = 1 */
    } else if (value && s->latched) { /* rising edge: shift out the next bit */
        unsigned b = s->bit < 16 ? (s->word >> (15 - s->bit)) & 1u : 0u;
        s->bit++;
        set_dout(s, b);
    }
}

static void on_pulse_pin(struct avr_irq_t *irq, uint32_t value, void *param)
{
    (void)irq;
    sim_t *s = param;
    value = value ? 1u : 0u;
    if (value && !s->pulse_level)
        s->pulse_rise = s->avr->cycle;
    else if (!value && s->pulse_level && s->pulse_rise)
        s->pulse_width = s->avr->cycle - s->pulse_rise; /* a complete high pulse */
    s->pulse_level = value;
    if (s->plog)
        fprintf(s->plog, "P %llu %u\n", (unsigned long long)s->avr->cycle, value ? 1u : 0u);
}

static void on_uart_in(struct avr_irq_t *irq, uint32_t value, void *param)
{
    (void)irq;
    sim_t *s = param;
    if (s->plog && (value & 0xFF) == 0)
        fprintf(s->plog, "RX %llu\n", (unsigned long long)s->avr->cycle);
}

static double enc_theta(const sim_t *s, double t_us)
{
    double th = 0.0;
    for (int k = 0; k < s->n_seg; k++) {
        if (t_us < s->seg[k].t0)
            break;
        double t = (t_us < s->seg[k].t1 ? t_us : s->seg[k].t1) - s->seg[k].t0;
        th = s->seg[k].th0 + s->seg[k].a * sin(s->seg[k].w * t * 1e-6);
    }
    return th;
}

static void enc_set_lines(sim_t *s)
{
    static const unsigned gray[4] = {0, 1, 3, 2}; /* bit0 = A, bit1 = B */
    /* -P: count 0 (the rod hanging at rest) reads A = B = 1. Both lines held low from reset, when
     * EICRA still selects low-level INT2/INT3, start simavr 1.6's per-cycle level poll of the
     * external interrupt, which runs until a line rises: the emulation then ran at 0.58 of real
     * time (measured with the rod at rest; counts 1..3 and event-file runs that leave count 0 run
     * at 1.00). The firmware counts steps from the lines it reads at start, so the phase is free. */
    long phase = s->plant_fd >= 0 ? 2 : 0;
    unsigned st = gray[(((s->enc_count - s->enc_slip + phase) % 4) + 4) % 4];
    unsigned z = s->enc_index >= 0 && ((s->enc_count % s->cpr) + s->cpr) % s->cpr == s->enc_index;
    /* PD0 is driven only when an index is emulated: a low pin on INT0, still in its reset
     * low-level mode in a build without an index, starts simavr's per-cycle level poll */
    avr_ioport_external_t ext = {.name = 'D', .mask = s->enc_index >= 0 ? 0x0D : 0x0C,
                                 .value = ((st & 3u) << 2) | z};
    avr_ioctl(s->avr, AVR_IOCTL_IOPORT_SET_EXTERNAL('D'), &ext);
    avr_raise_irq(s->enc_a, st & 1u);
    avr_raise_irq(s->enc_b, (st >> 1) & 1u);
    if (s->enc_index >= 0) { /* after A/B: the firmware's INT0 sees the lines of the new count */
        if (z && !s->enc_z->value)
            s->index_edges++;
        avr_raise_irq(s->enc_z, z);
    }
}

static avr_cycle_count_t enc_timer(avr_t *avr, avr_cycle_count_t when, void *param)
{
    (void)avr;
    sim_t *s = param;
    double t_us = (double)(when - s->t1_start) / 16.0;
    double theta = s->plant_fd >= 0 ? s->plant_theta : enc_theta(s, t_us);
    long target = (long)floor(theta * (double)s->cpr / (2.0 * M_PI) + s->enc_mount);
    long lag = labs(target - s->enc_count);
    if (lag > s->enc_max_lag)
        s->enc_max_lag = lag;
    if (target != s->enc_count) {
        long step = target > s->enc_count ? 1 : -1;
        s->enc_count += step;
        if (s->slip_n > 0 && t_us >= s->slip_t) { /* a drop-out: the lines do not show this step */
            s->enc_slip += step;
            s->slip_n--;
        }
        s->enc_steps++;
        enc_set_lines(s);
    }
    return when + 16; /* every microsecond */
}

static avr_cycle_count_t plant_timer(avr_t *avr, avr_cycle_count_t when, void *param);

static void on_tccr1b(struct avr_irq_t *irq, uint32_t value, void *param)
{
    (void)irq;
    sim_t *s = param;
    if (s->t1_start || (value & 0x07) == 0)
        return;
    s->t1_start = s->avr->cycle;
    if (s->plog)
        fprintf(s->plog, "T1START %llu\n", (unsigned long long)s->t1_start);
    if (s->n_seg || s->plant_fd >= 0)
        avr_cycle_timer_register(s->avr, 16, enc_timer, s);
    if (s->plant_fd >= 0) /* on the grid k * US from reset, the plant's own time steps */
        avr_cycle_timer_register(s->avr, s->plant_every - s->avr->cycle % s->plant_every, plant_timer, s);
}

/* ------------------------------------------------------------------ closed-loop plant (-P) */
static int full_io(int fd, void *buf, size_t n, int writing)
{
    uint8_t *p = buf;
    while (n) {
        ssize_t r = writing ? write(fd, p, n) : read(fd, p, n);
        if (r < 0 && errno == EINTR)
            continue;
        if (r <= 0)
            return -1;
        p += r;
        n -= (size_t)r;
    }
    return 0;
}

static int plant_connect(sim_t *s, const char *path)
{
    struct sockaddr_un a = {.sun_family = AF_UNIX};
    if (strlen(path) >= sizeof a.sun_path) {
        fprintf(stderr, "plant socket path too long: %s\n", path);
        return -1;
    }
    strcpy(a.sun_path, path);
    s->plant_fd = socket(AF_UNIX, SOCK_STREAM, 0);
    if (s->plant_fd < 0 || connect(s->plant_fd, (struct sockaddr *)&a, sizeof a) != 0) {
        fprintf(stderr, "cannot connect to the plant at %s: %s\n", path, strerror(errno));
        return -1;
    }
    return 0;
}

/* Every plant_every cycles: send (t, pulse), block until theta comes back (MCU time stands still). */
static avr_cycle_count_t plant_timer(avr_t *avr, avr_cycle_count_t when, void *param)
{
    sim_t *s = param;
    double out[2] = {(double)when / (double)avr->frequency, (double)s->pulse_width / (double)avr->frequency};
    double theta;
    if (full_io(s->plant_fd, out, sizeof out, 1) != 0 || full_io(s->plant_fd, &theta, sizeof theta, 0) != 0) {
        printf("PLANTLOST\n");
        fflush(stdout);
        stop = 1;
        return 0;
    }
    s->plant_theta = theta;
    s->plant_exchanges++;
    return when + s->plant_every;
}

/* ------------------------------------------------------------------ host link (pty) */
/* Follow one byte of a COBS-framed stream (firmware/PROTOCOL.md): its position in the frame and the
 * frame's type (the byte after the code byte). 1 at the 0x00 that ends a frame of type *type. */
static int frame_byte(uint8_t b, unsigned *pos, uint8_t *type)
{
    if (b == 0) {
        *pos = 0;
        return 1;
    }
    if ((*pos)++ == 1)
        *type = b;
    return 0;
}

static void on_link_out(struct avr_irq_t *irq, uint32_t value, void *param)
{
    (void)irq;
    link_t *l = param;
    if (l->out_len == LINK_OUT_SIZE) {
        l->out_dropped++;
        return;
    }
    l->out[(l->out_head + l->out_len) % LINK_OUT_SIZE] = (uint8_t)value;
    l->out_len++;
    /* a sample frame's delimiter: link_service arms the -H hold */
    if (frame_byte((uint8_t)value, &l->out_pos, &l->out_type) &&
        (l->out_type == LINK_T_SAMPLE || l->out_type == LINK_T_SAMPLE_PULSE))
        l->sample_out = 1;
}

static void on_link_xoff(struct avr_irq_t *irq, uint32_t value, void *param)
{
    (void)irq;
    ((link_t *)param)->xoff = value != 0;
}

static int link_open(link_t *l, avr_t *avr)
{
    if (openpty(&l->fd, &l->slave, l->slavename, NULL, NULL) < 0) {
        fprintf(stderr, "cannot create a pty: %s\n", strerror(errno));
        return -1;
    }
    struct termios tio;
    tcgetattr(l->fd, &tio);
    cfmakeraw(&tio);
    tcsetattr(l->fd, TCSANOW, &tio);
    /* The host connects through a name of this process's own, not /dev/pts/N: once this process has
     * exited, a host that reconnects (SerialLink does, as to a board unplugged) finds no such file,
     * instead of the pty the kernel has meanwhile given to another harness (another test), whose
     * frames it would read as ours. */
    const char *dir = getenv("TMPDIR");
    snprintf(l->path, sizeof l->path, "%s/aeropend-simavr-%ld.pty", dir && *dir ? dir : "/tmp", (long)getpid());
    unlink(l->path);
    if (symlink(l->slavename, l->path) != 0) {
        fprintf(stderr, "cannot create %s: %s\n", l->path, strerror(errno));
        return -1;
    }
    fcntl(l->fd, F_SETFL, fcntl(l->fd, F_GETFL) | O_NONBLOCK);
    uint32_t f = 0; /* binary stream: no stdio echo of the UART's bytes */
    avr_ioctl(avr, AVR_IOCTL_UART_GET_FLAGS('0'), &f);
    f &= ~AVR_UART_FLAG_STDIO;
    avr_ioctl(avr, AVR_IOCTL_UART_SET_FLAGS('0'), &f);
    l->rx = avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_INPUT);
    avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_OUTPUT), on_link_out, l);
    avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_OUT_XOFF), on_link_xoff, l);
    return 0;
}

/* Bytes the host has not read yet from the pty. */
static size_t link_unread(const link_t *l)
{
    int n = 0;
    return ioctl(l->slave, FIONREAD, &n) == 0 && n > 0 ? (size_t)n : 0;
}

/* Write to the pty what keeps the host's unread bytes within LINK_PTY_MAX (non-blocking). */
static void link_write(link_t *l)
{
    size_t room = LINK_PTY_MAX - (link_unread(l) < LINK_PTY_MAX ? link_unread(l) : LINK_PTY_MAX);
    while (l->out_len && room) {
        size_t run = LINK_OUT_SIZE - l->out_head;
        if (run > l->out_len)
            run = l->out_len;
        if (run > room)
            run = room;
        ssize_t w = write(l->fd, l->out + l->out_head, run);
        if (w <= 0)
            return; /* EAGAIN: the pty is full (host behind); EIO: no host */
        l->out_head = (l->out_head + (size_t)w) % LINK_OUT_SIZE;
        l->out_len -= (size_t)w;
        room -= (size_t)w;
    }
}

/* Read what the host has sent (non-blocking) behind the bytes not yet given to the UART, and note
 * a whole DUTY or PULSE frame among them (-H: the host's answer). */
static void link_read(link_t *l)
{
    if (l->in_done == l->in_len)
        l->in_done = l->in_len = 0;
    if (l->in_len == sizeof l->in)
        return;
    ssize_t r = read(l->fd, l->in + l->in_len, sizeof l->in - l->in_len);
    for (ssize_t i = 0; i < r; i++)
        if (frame_byte(l->in[l->in_len + (size_t)i], &l->in_pos, &l->in_type) &&
            (l->in_type == LINK_T_DUTY || l->in_type == LINK_T_PULSE))
            l->answered = 1;
    if (r > 0)
        l->in_len += (size_t)r;
}

/* Called after every avr_run() step, in the emulation thread. */
static void link_service(link_t *l, avr_t *avr)
{
    if (l->sample_out) { /* -H: hold after this sample frame only while the host answers every one */
        l->sample_out = 0;
        l->streak = l->answered ? l->streak + 1 : 0;
        l->hold_armed = l->hold_cycles && l->streak >= LINK_HOLD_STREAK;
        l->hold_at = avr->cycle + l->hold_cycles;
        l->answered = 0;
    }
    if (avr->cycle >= l->next_io) {
        l->next_io = avr->cycle + LINK_IO_CYCLES;
        link_write(l);
        link_read(l);
    }
    /* a byte sent before the firmware enabled its receiver waits (the UART would drop it) */
    if (avr->cycle >= l->next_feed && l->in_done < l->in_len && !l->xoff &&
        (avr->data[UCSR0B_ADDR] & (1 << RXEN0_BIT))) {
        avr_raise_irq(l->rx, l->in[l->in_done++]);
        l->next_feed = avr->cycle + LINK_BYTE_CYCLES;
    }
}

/* -H: at the armed cycle, while the host has not answered the MCU's last sample frame, let
 * wall-clock time pass (MCU time stands still), at most LINK_HOLD_MAX_US. */
static void link_hold(link_t *l, avr_t *avr)
{
    if (!l->hold_armed || avr->cycle < l->hold_at)
        return;
    l->hold_armed = 0;
    link_write(l);
    link_read(l);
    if (l->answered)
        return;
    l->holds++;
    const struct timespec tick = {0, 20000}; /* 20 us */
    struct timespec t0, now;
    clock_gettime(CLOCK_MONOTONIC, &t0);
    while (!l->answered && !stop) {
        clock_gettime(CLOCK_MONOTONIC, &now);
        if ((now.tv_sec - t0.tv_sec) * 1000000L + (now.tv_nsec - t0.tv_nsec) / 1000L >= LINK_HOLD_MAX_US) {
            l->hold_timeouts++;
            return;
        }
        nanosleep(&tick, NULL);
        link_write(l);
        link_read(l);
    }
}

/* Flow control: while the host is behind by more than LINK_OUT_HIGH bytes (beyond LINK_PTY_MAX in
 * the pty), let wall-clock time pass (MCU time stands still), so the host's view of MCU time lags
 * by ~0.3 s at most. */
static void link_wait_below_high(link_t *l)
{
    const struct timespec tick = {0, 200000}; /* 0.2 ms */
    while (!stop && l->out_len > LINK_OUT_HIGH) {
        nanosleep(&tick, NULL);
        link_write(l);
    }
}

/* On exit: wait until the host has read every byte of the MCU's: the buffer empty and nothing
 * unread in the pty for LINK_QUIET_MS in a row (FIONREAD counts only what the kernel has already
 * moved to the slave's read buffer; bytes still in its flip buffers, moved by a kernel worker that
 * a loaded host runs late, show as 0, and closing the master would discard them). At most
 * timeout_ms; a host that stopped reading, or SIGTERM / SIGINT, ends the wait. */
#define LINK_QUIET_MS 300
static void link_flush(link_t *l, int timeout_ms)
{
    const struct timespec tick = {0, 1000000}; /* 1 ms */
    int quiet = 0;
    for (int waited = 0; quiet < LINK_QUIET_MS && waited < timeout_ms && !stop; waited++) {
        nanosleep(&tick, NULL);
        link_write(l);
        quiet = l->out_len || link_unread(l) ? 0 : quiet + 1;
    }
}

static int read_events(const char *path, sim_t *s)
{
    FILE *f = fopen(path, "r");
    if (!f) {
        fprintf(stderr, "cannot open event file %s\n", path);
        return -1;
    }
    s->ir = calloc(MAX_EVENTS, sizeof *s->ir);
    s->ssi = calloc(MAX_EVENTS, sizeof *s->ssi);
    char line[256], kind[16];
    double t;
    char val[32];
    while (fgets(line, sizeof line, f)) {
        char *hash = strchr(line, '#');
        if (hash)
            *hash = 0;
        if (sscanf(line, "%15s", kind) == 1 && strcmp(kind, "enccpr") == 0) {
            s->cpr = strtol(line + 6, NULL, 0);
            continue;
        }
        if (strcmp(kind, "encindex") == 0) {
            s->enc_index = strtol(line + 8, NULL, 0);
            continue;
        }
        if (strcmp(kind, "encslip") == 0) {
            if (sscanf(line, "%*s %lf %ld", &s->slip_t, &s->slip_n) != 2 || s->slip_t < 0) {
                fprintf(stderr, "bad encslip line: %s", line);
                fclose(f);
                return -1;
            }
            continue;
        }
        if (strcmp(kind, "enc") == 0 && s->n_seg < MAX_SEGMENTS) {
            double *g = &s->seg[s->n_seg].t0;
            if (sscanf(line, "%*s %lf %lf %lf %lf %lf", g, g + 1, g + 2, g + 3, g + 4) == 5) {
                s->n_seg++;
                continue;
            }
        }
        if (sscanf(line, "%15s %lf %31s", kind, &t, val) != 3)
            continue;
        if (t < 0) {
            fprintf(stderr, "negative event time: %s", line);
            fclose(f);
            return -1;
        }
        unsigned v = (unsigned)strtoul(val, NULL, 0);
        event_t **arr = strcmp(kind, "ir") == 0 ? &s->ir : strcmp(kind, "ssi") == 0 ? &s->ssi : NULL;
        int *n = arr == &s->ir ? &s->n_ir : &s->n_ssi;
        if (!arr || *n >= MAX_EVENTS) {
            fprintf(stderr, "bad event line: %s", line);
            fclose(f);
            return -1;
        }
        if (*n && (*arr)[*n - 1].t_us > t) {
            fprintf(stderr, "events not sorted: %s", line);
            fclose(f);
            return -1;
        }
        (*arr)[*n].t_us = t;
        (*arr)[*n].value = v;
        (*n)++;
    }
    fclose(f);
    return 0;
}

int main(int argc, char **argv)
{
    const char *pos[6] = {0};
    int npos = 0;
    const char *events = NULL, *pulses = NULL, *plant = NULL;
    double plant_us = 1000.0, enc_mount = 0.0, hold_us = 0.0;
    int dump_regs = 0;
    for (int i = 1; i < argc; i++) {
        if (strcmp(argv[i], "-e") == 0 && i + 1 < argc)
            events = argv[++i];
        else if (strcmp(argv[i], "-p") == 0 && i + 1 < argc)
            pulses = argv[++i];
        else if (strcmp(argv[i], "-P") == 0 && i + 1 < argc)
            plant = argv[++i];
        else if (strcmp(argv[i], "-Q") == 0 && i + 1 < argc)
            plant_us = atof(argv[++i]);
        else if (strcmp(argv[i], "-M") == 0 && i + 1 < argc)
            enc_mount = atof(argv[++i]);
        else if (strcmp(argv[i], "-H") == 0 && i + 1 < argc)
            hold_us = atof(argv[++i]);
        else if (strcmp(argv[i], "-r") == 0)
            dump_regs = 1;
        else if (npos < 6)
            pos[npos++] = argv[i];
    }
    if (npos < 1) {
        fprintf(stderr, "usage: %s firmware.elf [cycles [A0_mV A1_mV A2_mV A3_mV]] [-e events] [-p pulses] [-P socket [-Q us] [-M counts]] [-H us] [-r]\n",
                argv[0]);
        return 2;
    }
    elf_firmware_t fw;
    memset(&fw, 0, sizeof fw);
    if (elf_read_firmware(pos[0], &fw) != 0) {
        fprintf(stderr, "cannot read firmware %s\n", pos[0]);
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

    static sim_t s;
    s.avr = avr;
    s.cs = 1;
    s.clk = 1;
    s.min_clkfe = s.min_half = s.min_read = ~(avr_cycle_count_t)0;
    s.min_rises = ~0u;
    s.cpr = 4000;
    s.plant_fd = -1;
    s.enc_index = -1;
    s.enc_mount = enc_mount;
    if (events && read_events(events, &s) != 0)
        return 2;
    if (plant && (plant_us < 1.0 || plant_connect(&s, plant) != 0))
        return 2;
    s.plant_every = (avr_cycle_count_t)(plant_us * (avr->frequency / 1e6) + 0.5);
    if (pulses && !(s.plog = fopen(pulses, "w"))) {
        fprintf(stderr, "cannot write pulse log %s\n", pulses);
        return 2;
    }
    if (s.plog || plant)
        avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_IOPORT_GETIRQ('E'), 3), on_pulse_pin, &s);
    if (s.plog)
        avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_INPUT), on_uart_in, &s);
    s.enc_a = avr_io_getirq(avr, AVR_IOCTL_IOPORT_GETIRQ('D'), 2);
    s.enc_b = avr_io_getirq(avr, AVR_IOCTL_IOPORT_GETIRQ('D'), 3);
    s.enc_z = avr_io_getirq(avr, AVR_IOCTL_IOPORT_GETIRQ('D'), 0);
    if (s.n_seg || plant)
        enc_set_lines(&s);
    avr_irq_register_notify(avr_iomem_getirq(avr, TCCR1B_ADDR, NULL, AVR_IOMEM_IRQ_ALL), on_tccr1b, &s);
    s.icp = avr_io_getirq(avr, AVR_IOCTL_IOPORT_GETIRQ('L'), 0);
    s.dout = avr_io_getirq(avr, AVR_IOCTL_IOPORT_GETIRQ('A'), 2);
    avr_irq_register_notify(avr_iomem_getirq(avr, TCCR4B_ADDR, NULL, AVR_IOMEM_IRQ_ALL), on_tccr4b, &s);
    avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_IOPORT_GETIRQ('A'), 0), on_csn, &s);
    avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_IOPORT_GETIRQ('A'), 1), on_clk, &s);
    set_dout(&s, 1);

    static link_t link;
    if (link_open(&link, avr) != 0)
        return 2;
    link.hold_cycles = (avr_cycle_count_t)(hold_us * (avr->frequency / 1e6) + 0.5);

    unsigned long long max_cycles = npos > 1 ? strtoull(pos[1], NULL, 10) : 0;
    int mv[4] = {500, 1000, 2500, 1250};
    for (int i = 0; i < 4 && 2 + i < npos; i++)
        mv[i] = atoi(pos[2 + i]);
    for (int i = 0; i < 4; i++)
        avr_raise_irq(avr_io_getirq(avr, AVR_IOCTL_ADC_GETIRQ, ADC_IRQ_ADC0 + i), (uint32_t)mv[i]);

    signal(SIGTERM, on_signal);
    signal(SIGINT, on_signal);
    printf("PTY %s\n", link.path);
    fflush(stdout);

    int state = cpu_Running;
    while (!stop && state != cpu_Done && state != cpu_Crashed &&
           (max_cycles == 0 || avr->cycle < max_cycles)) {
        state = avr_run(avr);
        link_service(&link, avr);
        link_hold(&link, avr);
        link_wait_below_high(&link);
    }
    link_flush(&link, 10000);
    printf("CYCLES %llu\n", (unsigned long long)avr->cycle);
    if (dump_regs)
        for (size_t i = 0; i < sizeof REGS / sizeof REGS[0]; i++)
            printf("REG %s %u\n", REGS[i].name, avr->data[REGS[i].addr]);
    if (events)
        printf("IREDGES %lu\nSSIREADS %u %u\n", s.ir_edges, s.reads, s.bad_reads);
    if (s.n_seg && !plant)
        printf("ENC %ld %ld %ld\n", s.enc_steps, s.enc_count, s.enc_max_lag);
    if (s.enc_index >= 0)
        printf("INDEX %ld\n", s.index_edges);
    if (plant)
        printf("PLANT %lu %ld\n", s.plant_exchanges, s.enc_max_lag);
    if (link.hold_cycles)
        printf("HOLDS %lu %lu\n", link.holds, link.hold_timeouts);
    if (s.plog)
        fclose(s.plog);
    if (s.reads) /* ns; CLK rising edges per read-out (min max) */
        printf("SSITIMING clkfe_min %llu half_min %llu read_min %llu read_max %llu rises %u %u\n",
               (unsigned long long)(s.min_clkfe * 1000000000ull / avr->frequency),
               (unsigned long long)(s.min_half * 1000000000ull / avr->frequency),
               (unsigned long long)(s.min_read * 1000000000ull / avr->frequency),
               (unsigned long long)(s.max_read * 1000000000ull / avr->frequency), s.min_rises, s.max_rises);
    fflush(stdout);
    if (link.out_dropped || link.out_len || link_unread(&link))
        printf("LINKLOST %lu\n", link.out_dropped + (unsigned long)(link.out_len + link_unread(&link)));
    fflush(stdout);
    unlink(link.path);
    fprintf(stderr, "harness: stopped (cpu state %d, %llu cycles)\n", state,
            (unsigned long long)avr->cycle);
    _exit(state == cpu_Crashed ? 1 : 0);
}
