/*
 * aeropend acquisition/actuation firmware for the ATmega2560 (Arduino Mega 2560 + Arduino
 * Motor Shield Rev3), register level, F_CPU = 16 MHz. See firmware/PROTOCOL.md.
 *
 * Timer1  phase-correct 8-bit PWM (WGM1 = 0b0001), prescaler 64: f = 16e6 / (64 * 510)
 *         = 490.2 Hz on OC1A = PB5 = Mega D11 (shield channel B PWM; DIR B = D13 = PB7,
 *         BRAKE B = D8 = PH5). TOV1 at BOTTOM every 510 * 4 us = 2.040 ms starts a sample
 *         (the thesis' "2.048 ms" is 512 * 4 us; phase-correct 8-bit counts 510 steps).
 * ADC     interrupt-driven chain started in the TOV1 ISR, prescaler 128 (125 kHz, 104 us per
 *         conversion): i_a on A0 (AVcc ref), theta on A2 (AVcc ref), then v_a = A3 - A1
 *         differential, gain 1, internal 2.56 V ref (MUX5:0 = 0b010011, thesis §4.2.1): one
 *         discarded conversion after the reference switch, then the measurement.
 * Timer4  normal mode, prescaler 64 (4 us ticks), input capture on ICP4 = PL0 = Mega D49,
 *         rising edge, noise canceller; 16-bit ICR4 extended to 32 bits with an overflow
 *         counter (race-safe, see ap_capture_extend), spike rejection + median of three.
 * USART0  500000 baud 8N1 (U2X0, UBRR0 = 3, 0 % error), RX interrupt into a ring, TX ring
 *         drained by the UDRE interrupt.
 * Angle   default: AS5040 PWM output -> RC low-pass -> ADC2 (thesis §4.3.2). Build option
 *         ANGLE=ssi (-DANGLE_SSI): the AS5040's SSI read-out (thesis §4.3.1), bit-banged in the
 *         TOV1 ISR at the sample instant: CSn = PA0 (D22), CLK = PA1 (D23), DO = PA2 (D24,
 *         pull-up); 16-bit word checked for parity and status (ap_as5040_decode); no theta ADC
 *         conversion. The frame layout is the same (flags bit4..6, STATUS angle_errors).
 * Safety  command watchdog: no valid command for 250 ms -> duty 0 (flag bit1) until the next
 *         DUTY command; AVR hardware watchdog (120 ms) resets a hung main loop.
 */
#include <avr/interrupt.h>
#include <avr/io.h>
#include <avr/sleep.h>
#include <avr/wdt.h>
#include <stdint.h>
#include <util/atomic.h>

#include "protocol.h"

#ifndef I_A_CHANNEL
#define I_A_CHANNEL 0 /* A0 */
#endif
#ifndef THETA_CHANNEL
#define THETA_CHANNEL 2 /* A2 */
#endif
#define MUX_V_A 0x13             /* 0b010011: ADC3 (+) - ADC1 (-), gain 1 */
#define REF_AVCC (1 << REFS0)
#define REF_2V56 ((1 << REFS1) | (1 << REFS0))
#define TOV1_US 2040u            /* 510 ticks * 4 us */
#define WATCHDOG_TICKS 121u      /* trips at tick 122 after the last command: <= 248.9 ms, + <= 1 ms until
                                    the new OCR latches at TOP: duty 0 within 250 ms */
#define STATUS_EVERY 256u

#ifdef ANGLE_SSI
/* AS5040 SSI pins on PORTA (Mega D22..D24, free of the motor shield). */
#define SSI_CSN PA0
#define SSI_CLK PA1
#define SSI_DO PA2
#ifndef SSI_CLOCKS
#define SSI_CLOCKS 16 /* rising CLK edges per read-out; 16..22 (the thesis clocked 22) */
#endif
#if SSI_CLOCKS < 16 || SSI_CLOCKS > 22
#error "SSI_CLOCKS must be 16..22 (the AS5040 word has 16 bits)"
#endif
/* Delays in CPU cycles (62.5 ns). CLK high phase: 8 cycles (500 ns) from the rising edge to
 * sampling DO >= t_DO valid (375 ns) + the 1-cycle input synchroniser; CLK low phase: 6 cycles
 * + loop overhead; each half period >= 500 ns (CLK <= 1 MHz), CSn low to the first CLK fall
 * >= t_CLKFE (500 ns). test_firmware_simavr_io.py measures the emulated pin timing. */
#define SSI_HIGH_CYCLES 8
#define SSI_LOW_CYCLES 6
#endif

/* ------------------------------------------------------------------ UART rings */
#define TX_SIZE 256u /* power of two */
#define RX_SIZE 64u
static volatile uint8_t tx_buf[TX_SIZE];
static volatile uint8_t tx_head, tx_tail; /* head: next write, tail: next read (uint8 wraps) */
static volatile uint8_t rx_buf[RX_SIZE];
static volatile uint8_t rx_head, rx_tail;

/* ------------------------------------------------------------------ shared state */
static volatile uint32_t t_us;          /* time of the current TOV1 [us] */
static volatile uint8_t duty_target;    /* requested OCR (0 after watchdog / disable) */
static volatile uint8_t duty_written;   /* OCR written at the previous TOV1 */
static volatile uint8_t enabled = 1;
static volatile uint8_t wd_tripped;
static volatile uint8_t ticks_since_cmd;
static volatile uint8_t rate_div = 1, rate_cnt;
static volatile int16_t i_a_offset, theta_offset;
static volatile uint16_t seq, rx_frames, rx_errors, tx_overflows, wd_trips;
static volatile uint16_t t4_ovf;        /* Timer4 overflow count (upper 16 bits) */
static ap_speed_t speed;                /* touched only with interrupts disabled */
static volatile uint8_t adc_step;       /* 0 idle, 1 i_a, 2 theta, 3 v_a dummy, 4 v_a */
static ap_sample_t cur;                 /* sample being built by the ADC chain */
static ap_sample_t done;                /* last complete sample, handed to the main loop */
static volatile uint8_t sample_ready;
static uint8_t status_cnt;
#ifdef ANGLE_SSI
static uint16_t ssi_theta;              /* last valid raw angle [counts] */
static volatile uint16_t angle_errors;  /* rejected read-outs (wrapping) */

/* Read one 16-bit word from the AS5040 (~34 us at 16 MHz). Idle: CSn high,
 * CLK high. CSn low; the first falling CLK edge latches the angle; each rising edge shifts
 * out one bit (MSB first), read before the next falling edge; SSI_CLOCKS - 16 extra clocks
 * (thesis: 22 in all) shift out the daisy-chain input and are ignored; then CSn high. */
static uint16_t ssi_read(void)
{
    uint16_t w = 0;
    PORTA &= (uint8_t)~(1 << SSI_CSN);
    __builtin_avr_delay_cycles(SSI_HIGH_CYCLES);
    PORTA &= (uint8_t)~(1 << SSI_CLK);
    for (uint8_t i = 0; i < SSI_CLOCKS; i++) {
        __builtin_avr_delay_cycles(SSI_LOW_CYCLES);
        PORTA |= (1 << SSI_CLK);
        __builtin_avr_delay_cycles(SSI_HIGH_CYCLES);
        if (i < 16)
            w = (uint16_t)((w << 1) | ((PINA >> SSI_DO) & 1u));
        if (i + 1 < SSI_CLOCKS)
            PORTA &= (uint8_t)~(1 << SSI_CLK);
    }
    PORTA |= (1 << SSI_CSN); /* CLK is high again: idle; next read >= t_CSn (500 ns) later */
    return w;
}
#endif

static void tx_push_frame(const uint8_t *wire, uint8_t n, uint8_t is_sample)
{
    /* Called with interrupts disabled (ISR context). */
    uint8_t used = (uint8_t)(tx_head - tx_tail);
    if ((uint16_t)used + n >= TX_SIZE) {
        if (is_sample)
            tx_overflows++;
        return;
    }
    for (uint8_t i = 0; i < n; i++)
        tx_buf[(uint8_t)(tx_head + i) & (TX_SIZE - 1)] = wire[i];
    tx_head = (uint8_t)(tx_head + n);
    UCSR0B |= (1 << UDRIE0);
}

ISR(USART0_UDRE_vect)
{
    if (tx_head == tx_tail) {
        UCSR0B &= (uint8_t)~(1 << UDRIE0);
        return;
    }
    UDR0 = tx_buf[tx_tail & (TX_SIZE - 1)];
    tx_tail++;
}

ISR(USART0_RX_vect)
{
    uint8_t b = UDR0;
    uint8_t next = (uint8_t)((rx_head + 1) & (RX_SIZE - 1));
    if (next != rx_tail) {
        rx_buf[rx_head] = b;
        rx_head = next;
    }
}

/* ------------------------------------------------------------------ Timer4 capture */
ISR(TIMER4_OVF_vect) { t4_ovf++; }

static uint32_t t4_now(void)
{
    /* Interrupts are disabled here (ISR or atomic block). */
    uint16_t c = TCNT4;
    uint8_t pending = (TIFR4 & (1 << TOV4)) ? 1 : 0;
    return ap_capture_extend(c, t4_ovf, pending);
}

ISR(TIMER4_CAPT_vect)
{
    uint16_t icr = ICR4;
    uint8_t pending = (TIFR4 & (1 << TOV4)) ? 1 : 0;
    ap_speed_edge(&speed, ap_capture_extend(icr, t4_ovf, pending));
}

/* ------------------------------------------------------------------ sampling */
static void adc_start(uint8_t ref, uint8_t mux)
{
    ADMUX = (uint8_t)(ref | (mux & 0x1F));
    if (mux & 0x20)
        ADCSRB |= (1 << MUX5);
    else
        ADCSRB &= (uint8_t)~(1 << MUX5);
    ADCSRA |= (1 << ADSC);
}

ISR(TIMER1_OVF_vect)
{
    t_us += TOV1_US;
    /* Command watchdog. */
    if (ticks_since_cmd < 255)
        ticks_since_cmd++;
    if (ticks_since_cmd > WATCHDOG_TICKS && !wd_tripped) {
        wd_tripped = 1;
        wd_trips++;
        duty_target = 0;
    }
    uint8_t applied = duty_written; /* latched at the TOP inside the interval now ending */
    uint8_t next = enabled ? duty_target : 0;
    OCR1A = next;
    duty_written = next;
    if (++rate_cnt < rate_div || adc_step != 0)
        return;
    rate_cnt = 0;
    cur.t_us = t_us;
    cur.duty = applied;
    uint8_t stale;
    cur.period = ap_speed_period(&speed, t4_now(), &stale);
    cur.flags = (uint8_t)((enabled ? AP_FLAG_ENABLED : 0) | (wd_tripped ? AP_FLAG_WATCHDOG : 0) |
                          (speed.spike ? AP_FLAG_SPIKE : 0) | (stale ? AP_FLAG_SPEED_STALE : 0));
    adc_step = 1;
    adc_start(REF_AVCC, I_A_CHANNEL);
#ifdef ANGLE_SSI
    /* Read while the i_a conversion runs (104 us): the angle at the sample instant. Interrupts
     * are re-enabled for the ~34 us bit-bang so the UART RX/UDRE and Timer4 interrupts are not
     * held off (RX overrun at 500 kbaud after ~3 byte times). Safe: everything shared is done
     * above; TOV1 cannot recur for 2 ms; the ADC chain publishes `cur` only 3 conversions
     * (>= 300 us) later; only this ISR writes angle_errors / ssi_theta / cur.theta; SSI has no
     * clock timeout, so a stretched clock phase is harmless. */
    sei();
    uint16_t angle;
    uint8_t st = ap_as5040_decode(ssi_read(), &angle);
    if (st & AP_SSI_INVALID) {
        angle_errors++;
        cur.flags |= AP_FLAG_ANGLE_INVALID; /* theta repeats the last valid angle */
    } else {
        ssi_theta = angle;
    }
    if (st & AP_SSI_W_LIN)
        cur.flags |= AP_FLAG_ANGLE_LIN;
    cur.flags |= AP_FLAG_ANGLE_SSI;
    cur.theta = (uint16_t)(((int16_t)ssi_theta - theta_offset) & 0x3FF);
#endif
}

ISR(ADC_vect)
{
    uint16_t raw = ADC;
    switch (adc_step) {
    case 1:
        cur.i_a = (int16_t)((int16_t)raw - i_a_offset);
#ifdef ANGLE_SSI
        adc_step = 3; /* theta came over SSI: go straight to v_a */
        adc_start(REF_2V56, MUX_V_A);
#else
        adc_step = 2;
        adc_start(REF_AVCC, THETA_CHANNEL);
#endif
        break;
    case 2:
        cur.theta = (uint16_t)(((int16_t)raw - theta_offset) & 0x3FF);
        adc_step = 3;
        adc_start(REF_2V56, MUX_V_A); /* first conversion after a reference switch: discard */
        break;
    case 3:
        adc_step = 4;
        adc_start(REF_2V56, MUX_V_A);
        break;
    default: {
        /* 10-bit two's complement -> int16 */
        cur.v_a = (int16_t)((raw & 0x200) ? (int16_t)(raw | 0xFC00) : (int16_t)raw);
        adc_step = 0;
        done = cur; /* packed + framed in the main loop: keeps this ISR short (RX at 20 us/byte) */
        sample_ready = 1;
        break;
    }
    }
}

/* ------------------------------------------------------------------ commands */
static void apply_command(const ap_command_t *c)
{
    switch (c->type) {
    case AP_T_DUTY: {
        uint8_t ocr = (uint8_t)(((uint32_t)c->value * 255u + 32767u) / 65535u);
        ATOMIC_BLOCK(ATOMIC_RESTORESTATE) { duty_target = ocr; wd_tripped = 0; }
        break;
    }
    case AP_T_ENABLE: enabled = (uint8_t)c->value; break;
    case AP_T_RATE: rate_div = (uint8_t)c->value; break;
    case AP_T_CALIBRATE:
        ATOMIC_BLOCK(ATOMIC_RESTORESTATE) {
            if (c->item == AP_CAL_I_A_OFFSET) i_a_offset = c->offset;
            else theta_offset = c->offset;
        }
        break;
    default: break;
    }
}

static void hw_init(void)
{
    /* Motor shield channel B: PWM D11 = PB5 (OC1A), DIR D13 = PB7 high, BRAKE D8 = PH5 low. */
    DDRB |= (1 << PB5) | (1 << PB7);
    PORTB |= (1 << PB7);
    DDRH |= (1 << PH5);
    PORTH &= (uint8_t)~(1 << PH5);
    OCR1A = 0;
#ifdef SIMAVR_TIMER1
    /* Emulator build only: simavr 1.6 does not implement Timer1 phase-correct PWM on the
     * ATmega2560 (writes to OCR1A are "UNSUPPORTED", TOV1 comes every 65536 ticks). Fast PWM
     * with TOP = ICR1 = 509 gives the same 510-tick (2.040 ms) TOV1 period. */
    ICR1 = 509;
    TCCR1A = (1 << COM1A1) | (1 << WGM11);
    TCCR1B = (1 << WGM13) | (1 << WGM12) | (1 << CS11) | (1 << CS10);
#else
    TCCR1A = (1 << COM1A1) | (1 << WGM10);  /* non-inverting, phase-correct 8-bit */
    TCCR1B = (1 << CS11) | (1 << CS10);     /* prescaler 64 */
#endif
    TIMSK1 = (1 << TOIE1);
#ifdef ANGLE_SSI
    /* AS5040 SSI: CSn, CLK outputs idling high; DO input with pull-up (defined level when the
     * sensor is absent: an all-ones word has COF = 1 and is rejected). */
    PORTA |= (1 << SSI_CSN) | (1 << SSI_CLK) | (1 << SSI_DO);
    DDRA |= (1 << SSI_CSN) | (1 << SSI_CLK);
#endif
    /* ADC: enabled, interrupt, prescaler 128; digital input buffers off on A0-A3. */
    DIDR0 = 0x0F;
    ADCSRA = (1 << ADEN) | (1 << ADIE) | (1 << ADPS2) | (1 << ADPS1) | (1 << ADPS0);
    /* Timer4: normal mode, prescaler 64, input capture rising edge + noise canceller. */
    DDRL &= (uint8_t)~(1 << PL0);
    TCCR4A = 0;
    TCCR4B = (1 << ICNC4) | (1 << ICES4) | (1 << CS41) | (1 << CS40);
    TIMSK4 = (1 << ICIE4) | (1 << TOIE4);
    /* USART0: 500000 baud, U2X, 8N1. */
    UBRR0 = 3;
    UCSR0A = (1 << U2X0);
    UCSR0C = (1 << UCSZ01) | (1 << UCSZ00);
    UCSR0B = (1 << RXEN0) | (1 << TXEN0) | (1 << RXCIE0);
}

int main(void)
{
    MCUSR = 0;
    wdt_enable(WDTO_120MS);
    ap_speed_init(&speed);
    hw_init();
    sei();
    ap_decoder_t dec;
    ap_decoder_init(&dec);
    set_sleep_mode(SLEEP_MODE_IDLE);
    for (;;) {
        wdt_reset();
        /* Idle until an interrupt when there is nothing to do (timers, ADC and UART keep
         * running in idle mode); sei + sleep are atomic, so no wake-up is missed. */
        cli();
        if (rx_tail == rx_head && !sample_ready) {
            sleep_enable();
            sei();
            sleep_cpu();
            sleep_disable();
        }
        sei();
        while (rx_tail != rx_head) {
            uint8_t b = rx_buf[rx_tail];
            rx_tail = (uint8_t)((rx_tail + 1) & (RX_SIZE - 1));
            int r = ap_decoder_push(&dec, b);
            if (r < 0) {
                rx_errors++;
            } else if (r == 1) {
                ap_command_t c;
                if (ap_command_parse(dec.payload, dec.payload_len, &c) == AP_OK) {
                    rx_frames++;
                    ticks_since_cmd = 0;
                    apply_command(&c);
                } else {
                    rx_errors++;
                }
            }
        }
        if (sample_ready) {
            ap_sample_t smp;
            ATOMIC_BLOCK(ATOMIC_RESTORESTATE) { smp = done; sample_ready = 0; }
            smp.seq = seq;
            uint8_t payload[AP_SAMPLE_LEN], wire[AP_MAX_WIRE];
            ap_sample_pack(&smp, payload);
            uint8_t n = (uint8_t)ap_frame_encode(payload, AP_SAMPLE_LEN, wire);
            ATOMIC_BLOCK(ATOMIC_RESTORESTATE) {
                uint16_t before = tx_overflows;
                tx_push_frame(wire, n, 1);
                if (tx_overflows == before)
                    seq++; /* seq counts frames sent; a TX drop shows in tx_overflows */
            }
            if (++status_cnt == 0) { /* every STATUS_EVERY (256) samples */
                ap_status_t st;
                uint8_t payload[AP_STATUS_LEN], wire[AP_MAX_WIRE];
                ATOMIC_BLOCK(ATOMIC_RESTORESTATE) {
                    st.rx_frames = rx_frames; st.rx_errors = rx_errors;
                    st.tx_overflows = tx_overflows; st.watchdog_trips = wd_trips;
                    st.spikes = speed.spikes;
#ifdef ANGLE_SSI
                    st.angle_errors = angle_errors;
#else
                    st.angle_errors = 0;
#endif
                }
                ap_status_pack(&st, payload);
                uint8_t n = (uint8_t)ap_frame_encode(payload, AP_STATUS_LEN, wire);
                ATOMIC_BLOCK(ATOMIC_RESTORESTATE) { tx_push_frame(wire, n, 0); }
            }
        }
    }
}
