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
 *         ANGLE=encoder (-DANGLE_ENCODER): a quadrature encoder, A on INT2 = PD2 (D19), B on
 *         INT3 = PD3 (D18), pull-ups on, any-edge interrupts decoded x4 (ap_quad_step); theta =
 *         position mod ENC_CPR counts (0 at reset: the rod hangs down at power-up).
 *         ENC_INDEX=<count> (-DENC_INDEX_AT): the encoder's gated index Z on INT0 = PD0 (D21),
 *         rising edge: the first index edge sets the position to ENC_INDEX_AT (homing; until then
 *         flag bit5 says the angle counts from the power-up position), every later one checks it
 *         (a different count: counts were missed; flag bit4, STATUS angle_errors + 1, re-homed).
 * Actuator default: H-bridge PWM (above). ACTUATOR=esc (-DACT_ESC): a hobby ESC's servo pulse on
 *         OC3A = PE3 = Mega D5, Timer3 fast PWM (WGM3 = 14, TOP = ICR3), prescaler 8 (0.5 us):
 *         frame ESC_HZ (50..490 Hz), pulse ESC_MIN_US..ESC_MAX_US; after reset the minimum pulse
 *         for ESC_ARM_MS (arming, flag bit7), then the PULSE commands; no valid command for
 *         ESC_SILENCE_MS -> minimum (disarm) pulse. Timer1 keeps the 2.040 ms sample tick with OC1A
 *         disconnected; no armature channels (i_a, v_a sent as AP_ABSENT_I16).
 * Safety  command watchdog: no valid command for 250 ms (ESC: ESC_SILENCE_MS) -> duty 0 / minimum
 *         pulse (flag bit1) until the next DUTY / PULSE command; AVR hardware watchdog (120 ms)
 *         resets a hung main loop.
 * Hello   HELLO frame (actuator, sensor, channels, ESC timing, counts per revolution) after reset,
 *         on HELLO_REQ and after every STATUS frame.
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

#if defined(ANGLE_SSI) && defined(ANGLE_ENCODER)
#error "choose one angle interface: ANGLE_SSI or ANGLE_ENCODER"
#endif
#if !defined(ANGLE_SSI) && !defined(ANGLE_ENCODER)
#define ANGLE_ADC 1 /* theta from an ADC conversion (AS5040 PWM -> RC, or a potentiometer) */
#endif
#ifdef ACT_ESC
/* ESC servo pulse. All build-time; the HELLO frame announces them. */
#ifndef ESC_HZ
#define ESC_HZ 50
#endif
#ifndef ESC_MIN_US
#define ESC_MIN_US 1000
#endif
#ifndef ESC_MAX_US
#define ESC_MAX_US 2000
#endif
#ifndef ESC_ARM_MS
#define ESC_ARM_MS 2000
#endif
#ifndef ESC_SILENCE_MS
#define ESC_SILENCE_MS 60
#endif
#if ESC_HZ < 50 || ESC_HZ > 490
#error "ESC_HZ must be 50..490 (servo frame rate)"
#endif
#if ESC_MIN_US < 100 || ESC_MAX_US <= ESC_MIN_US || ESC_MAX_US * ESC_HZ >= 1000000L
#error "ESC pulse range must satisfy 100 <= ESC_MIN_US < ESC_MAX_US < frame period"
#endif
#define ESC_TOP ((F_CPU / 8UL + ESC_HZ / 2) / ESC_HZ - 1UL) /* ICR3: frame = (TOP + 1) * 0.5 us */
#define ESC_FRAME_US ((ESC_TOP + 1UL) / 2UL)
/* The disarm pulse must start within 100 ms of the last command: the watchdog trips at most
 * (ESC_WD_TICKS + 1) ticks after it, and the new OCR3A reaches the pin at the next frame start. */
#define ESC_WD_TICKS ((ESC_SILENCE_MS * 1000UL) / TOV1_US)
#if (ESC_WD_TICKS + 1UL) * TOV1_US + ESC_FRAME_US > 100000UL
#error "ESC_SILENCE_MS + one frame must stay below 100 ms (disarm within 100 ms of PC silence)"
#endif
#define ESC_ARM_TICKS ((ESC_ARM_MS * 1000UL + TOV1_US - 1UL) / TOV1_US)
#define WD_LIMIT ESC_WD_TICKS
#else
#define WD_LIMIT WATCHDOG_TICKS
#endif
#ifdef ANGLE_ENCODER
#ifndef ENC_CPR
#define ENC_CPR 4000 /* counts per revolution: lines x 4 (a 1000-line encoder) */
#endif
#if ENC_CPR < 4 || ENC_CPR > 65535
#error "ENC_CPR must be 4..65535 counts per revolution"
#endif
#if defined(ENC_INDEX_AT) && (ENC_INDEX_AT < 0 || ENC_INDEX_AT >= ENC_CPR)
#error "ENC_INDEX must be a count in 0..ENC_CPR-1 (the index's position from the rod hanging at rest)"
#endif
#endif

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
static volatile uint8_t hello_due = 1;  /* send a HELLO frame from the main loop */
#ifdef ACT_ESC
static volatile uint16_t pulse_target = 2u * ESC_MIN_US;  /* commanded pulse [0.5 us] */
static volatile uint16_t pulse_written = 2u * ESC_MIN_US; /* pulse set at the last tick, next frame's */
static volatile uint16_t arm_ticks = ESC_ARM_TICKS;       /* ticks of arming left */
#endif
#ifdef ANGLE_ENCODER
static volatile uint16_t enc_pos;       /* position in [0, ENC_CPR) */
static volatile uint8_t enc_lines;      /* last line state, bit0 = A, bit1 = B */
static volatile uint8_t enc_bad;        /* invalid transition since the last sample */
static volatile uint16_t angle_errors;  /* invalid transitions, index mismatches (wrapping) */
#ifdef ENC_INDEX_AT
static volatile uint8_t enc_homed;      /* an index edge has set the position since reset */
#endif
#endif
static ap_speed_t speed;                /* touched only with interrupts disabled */
static volatile uint8_t adc_step;       /* 0 idle, 1 i_a, 2 theta, 3 v_a dummy, 4 v_a */
static ap_sample_t cur;                 /* sample being built by the ADC chain */
static ap_sample_t done;                /* last complete sample, handed to the main loop */
#ifdef ACT_ESC
static uint16_t cur_pulse, done_pulse;  /* applied pulse [0.5 us] of cur / done */
#endif
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

#if defined(ACT_ESC) && defined(SIMAVR_TIMER1)
/* Emulator build only: simavr 1.6 writes OCR3A through (no double buffer), and a changed OCR
 * above the count re-raises the pin: a write at the tick would cut or stretch the running pulse
 * or add a spurious one. Writing at the frame start (TOV3, a few us after BOTTOM) does in
 * software what the hardware's double buffer does at BOTTOM. */
ISR(TIMER3_OVF_vect) { OCR3A = pulse_written - 1u; }
#endif

#ifdef ANGLE_ENCODER
/* ------------------------------------------------------------------ quadrature encoder */
/* Count the step from the last line state to the one on the pins now (interrupts off). */
static inline void enc_follow(void)
{
    uint8_t now = (uint8_t)((PIND >> PD2) & 3u); /* PD2 = A, PD3 = B */
    int8_t step = ap_quad_step(enc_lines, now);
    enc_lines = now;
    if (step == AP_QUAD_INVALID) {
        enc_bad = 1;
        angle_errors++;
    } else {
        enc_pos = ap_quad_wrap(enc_pos, step, ENC_CPR);
    }
}
ISR(INT2_vect) { enc_follow(); }
ISR(INT3_vect, ISR_ALIASOF(INT2_vect));
#ifdef ENC_INDEX_AT
/* A gated index is high during one count, ENC_INDEX_AT: its rising edge comes with the A/B edge
 * that enters that count from either side. INT0 outranks INT2/INT3, so that edge is counted here
 * first (the INT2/INT3 interrupt then finds the lines unchanged): the position at a rising index
 * edge is ENC_INDEX_AT in both directions. */
ISR(INT0_vect)
{
    enc_follow();
    if (enc_homed && enc_pos != (uint16_t)ENC_INDEX_AT) {
        enc_bad = 1; /* counts were missed (or gained) since the last index edge */
        angle_errors++;
    }
    enc_pos = (uint16_t)ENC_INDEX_AT;
    enc_homed = 1;
}
#endif
#endif

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
    if (ticks_since_cmd > WD_LIMIT && !wd_tripped) {
        wd_tripped = 1;
        wd_trips++;
        duty_target = 0;
#ifdef ACT_ESC
        pulse_target = 2u * ESC_MIN_US;
#endif
    }
#ifdef ACT_ESC
    uint16_t applied = pulse_written; /* reached the pin at the frame start after the last tick */
    if (arm_ticks)
        arm_ticks--;
    uint16_t next = (enabled && !arm_ticks) ? pulse_target : 2u * ESC_MIN_US;
    pulse_written = next;
#ifndef SIMAVR_TIMER1
    /* High for OCR3A + 1 ticks of 0.5 us. OCR3A is double-buffered in fast PWM: the new width
     * starts with the next frame (at BOTTOM), never inside the running pulse. */
    OCR3A = next - 1u;
#endif
#else
    uint8_t applied = duty_written; /* latched at the TOP inside the interval now ending */
    uint8_t next = enabled ? duty_target : 0;
    OCR1A = next;
    duty_written = next;
#endif
    if (++rate_cnt < rate_div || adc_step != 0)
        return;
    rate_cnt = 0;
    cur.t_us = t_us;
#ifdef ACT_ESC
    cur_pulse = applied;
    cur.duty = 0;
#else
    cur.duty = applied;
#endif
    uint8_t stale;
    cur.period = ap_speed_period(&speed, t4_now(), &stale);
    cur.flags = (uint8_t)((enabled ? AP_FLAG_ENABLED : 0) | (wd_tripped ? AP_FLAG_WATCHDOG : 0) |
                          (speed.spike ? AP_FLAG_SPIKE : 0) | (stale ? AP_FLAG_SPEED_STALE : 0));
#ifdef NO_SPEED
    cur.period = AP_ABSENT_U32;
    cur.flags &= (uint8_t)~(AP_FLAG_SPIKE | AP_FLAG_SPEED_STALE);
#endif
#ifdef ANGLE_ENCODER
    /* Interrupts are off in this ISR: the position is the one at the sample instant. */
    int32_t pos = (int32_t)enc_pos - theta_offset; /* no division: this ISR holds off the encoder */
    while (pos < 0)
        pos += ENC_CPR;
    while (pos >= (int32_t)ENC_CPR)
        pos -= ENC_CPR;
    cur.theta = (uint16_t)pos;
    if (enc_bad)
        cur.flags |= AP_FLAG_ANGLE_INVALID;
    enc_bad = 0;
#ifdef ENC_INDEX_AT
    if (!enc_homed)
        cur.flags |= AP_FLAG_ANGLE_UNHOMED;
#endif
#endif
#ifdef ACT_ESC
    if (arm_ticks)
        cur.flags |= AP_FLAG_ARMING;
    cur.i_a = AP_ABSENT_I16;
    cur.v_a = AP_ABSENT_I16;
#ifdef ANGLE_ADC
    adc_step = 2;
    adc_start(REF_AVCC, THETA_CHANNEL);
#else
    done = cur; /* nothing to convert: the sample is complete */
    done_pulse = cur_pulse;
    sample_ready = 1;
#endif
#else
    adc_step = 1;
    adc_start(REF_AVCC, I_A_CHANNEL);
#endif
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
#ifndef ANGLE_ADC
        adc_step = 3; /* theta came over SSI / from the encoder: go straight to v_a */
        adc_start(REF_2V56, MUX_V_A);
#else
        adc_step = 2;
        adc_start(REF_AVCC, THETA_CHANNEL);
#endif
        break;
    case 2:
        cur.theta = (uint16_t)(((int16_t)raw - theta_offset) & 0x3FF);
#ifdef ACT_ESC
        adc_step = 0; /* no armature channels: the sample is complete */
        done = cur;
        done_pulse = cur_pulse;
        sample_ready = 1;
#else
        adc_step = 3;
        adc_start(REF_2V56, MUX_V_A); /* first conversion after a reference switch: discard */
#endif
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
#ifdef ACT_ESC
    case AP_T_PULSE: {
        uint16_t v = c->value; /* clamped to the build's pulse range */
        if (v < 2u * ESC_MIN_US) v = 2u * ESC_MIN_US;
        if (v > 2u * ESC_MAX_US) v = 2u * ESC_MAX_US;
        ATOMIC_BLOCK(ATOMIC_RESTORESTATE) { pulse_target = v; wd_tripped = 0; }
        break;
    }
#else
    case AP_T_DUTY: {
        uint8_t ocr = (uint8_t)(((uint32_t)c->value * 255u + 32767u) / 65535u);
        ATOMIC_BLOCK(ATOMIC_RESTORESTATE) { duty_target = ocr; wd_tripped = 0; }
        break;
    }
#endif
    case AP_T_HELLO_REQ: hello_due = 1; break;
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

#ifdef ACT_ESC
#define COM1A_BITS 0 /* OC1A disconnected: Timer1 is only the sample tick */
#else
#define COM1A_BITS (1 << COM1A1)
#endif

static void hw_init(void)
{
#ifdef ACT_ESC
    /* ESC signal on OC3A = PE3 = D5: Timer3 fast PWM, TOP = ICR3, prescaler 8 (0.5 us ticks),
     * non-inverting; starts with the minimum pulse (arming). */
    DDRE |= (1 << PE3);
    ICR3 = (uint16_t)ESC_TOP;
    OCR3A = 2u * ESC_MIN_US - 1u;
    TCCR3A = (1 << COM3A1) | (1 << WGM31);
    TCCR3B = (1 << WGM33) | (1 << WGM32) | (1 << CS31);
#ifdef SIMAVR_TIMER1
    TIMSK3 = (1 << TOIE3);
#endif
#else
    /* Motor shield channel B: PWM D11 = PB5 (OC1A), DIR D13 = PB7 high, BRAKE D8 = PH5 low. */
    DDRB |= (1 << PB5) | (1 << PB7);
    PORTB |= (1 << PB7);
    DDRH |= (1 << PH5);
    PORTH &= (uint8_t)~(1 << PH5);
#endif
    OCR1A = 0;
#ifdef ANGLE_ENCODER
    /* Encoder A = PD2 (INT2, D19), B = PD3 (INT3, D18): inputs with pull-ups, any edge; with an
     * index, Z = PD0 (INT0, D21): input with pull-up, rising edge. The trigger is chosen with the
     * interrupts masked, then the flags a change of ISCn may have set are cleared, in one write
     * (simavr 1.6 stopped the emulated CPU after an EIFR write naming INTF0 alone that followed one
     * naming INTF2 and INTF3), then enabled. */
    uint8_t pins = (1 << PD2) | (1 << PD3), isc = (1 << ISC20) | (1 << ISC30);
    uint8_t flags = (1 << INTF2) | (1 << INTF3), mask = (1 << INT2) | (1 << INT3);
#ifdef ENC_INDEX_AT
    pins |= (1 << PD0);
    isc |= (1 << ISC01) | (1 << ISC00);
    flags |= (1 << INTF0);
    mask |= (1 << INT0);
#endif
    DDRD &= (uint8_t)~pins;
    PORTD |= pins;
    enc_lines = (uint8_t)((PIND >> PD2) & 3u);
    EICRA = (uint8_t)((EICRA & 0x0C) | isc);
    EIFR = flags;
    EIMSK |= mask;
#endif
#ifdef SIMAVR_TIMER1
    /* Emulator build only: simavr 1.6 does not implement Timer1 phase-correct PWM on the
     * ATmega2560 (writes to OCR1A are "UNSUPPORTED", TOV1 comes every 65536 ticks). Fast PWM
     * with TOP = ICR1 = 509 gives the same 510-tick (2.040 ms) TOV1 period. */
    ICR1 = 509;
    TCCR1A = COM1A_BITS | (1 << WGM11);
    TCCR1B = (1 << WGM13) | (1 << WGM12) | (1 << CS11) | (1 << CS10);
#else
    TCCR1A = COM1A_BITS | (1 << WGM10);     /* non-inverting, phase-correct 8-bit */
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

static void send_hello(void)
{
    ap_hello_t h;
#ifdef ACT_ESC
    h.actuator = AP_ACT_ESC;
    h.frame_hz = (uint16_t)((2000000UL + (ESC_TOP + 1UL) / 2UL) / (ESC_TOP + 1UL));
    h.pulse_min_us = ESC_MIN_US;
    h.pulse_max_us = ESC_MAX_US;
    h.arm_ms = ESC_ARM_MS;
    h.silence_ms = (uint16_t)(((ESC_WD_TICKS + 1UL) * TOV1_US + 500UL) / 1000UL);
    h.channels = AP_CH_THETA;
#else
    h.actuator = AP_ACT_HBRIDGE;
    h.frame_hz = 490;
    h.pulse_min_us = h.pulse_max_us = h.arm_ms = 0;
    h.silence_ms = (uint16_t)(((WATCHDOG_TICKS + 1UL) * TOV1_US + 500UL) / 1000UL);
    h.channels = AP_CH_I_A | AP_CH_V_A | AP_CH_THETA;
#endif
#ifndef NO_SPEED
    h.channels |= AP_CH_SPEED;
#endif
#if defined(ANGLE_ENCODER)
    h.sensor = AP_SENSOR_ENCODER;
    h.counts_per_rev = ENC_CPR;
#ifdef ENC_INDEX_AT
    h.channels |= AP_CH_INDEX;
#endif
#elif defined(ANGLE_SSI)
    h.sensor = AP_SENSOR_SSI;
    h.counts_per_rev = 1024;
#else
    h.sensor = AP_SENSOR_POT;
    h.counts_per_rev = 1024;
#endif
    uint8_t payload[AP_HELLO_LEN], wire[AP_MAX_WIRE];
    ap_hello_pack(&h, payload);
    uint8_t n = (uint8_t)ap_frame_encode(payload, AP_HELLO_LEN, wire);
    ATOMIC_BLOCK(ATOMIC_RESTORESTATE) { tx_push_frame(wire, n, 0); }
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
#ifdef ACT_ESC
            uint16_t pulse;
            ATOMIC_BLOCK(ATOMIC_RESTORESTATE) { smp = done; pulse = done_pulse; sample_ready = 0; }
            smp.seq = seq;
            uint8_t payload[AP_SAMPLE_PULSE_LEN], wire[AP_MAX_WIRE];
            ap_sample_pulse_pack(&smp, pulse, payload);
            uint8_t n = (uint8_t)ap_frame_encode(payload, AP_SAMPLE_PULSE_LEN, wire);
#else
            ATOMIC_BLOCK(ATOMIC_RESTORESTATE) { smp = done; sample_ready = 0; }
            smp.seq = seq;
            uint8_t payload[AP_SAMPLE_LEN], wire[AP_MAX_WIRE];
            ap_sample_pack(&smp, payload);
            uint8_t n = (uint8_t)ap_frame_encode(payload, AP_SAMPLE_LEN, wire);
#endif
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
#if defined(ANGLE_SSI) || defined(ANGLE_ENCODER)
                    st.angle_errors = angle_errors;
#else
                    st.angle_errors = 0;
#endif
                }
                ap_status_pack(&st, payload);
                uint8_t n = (uint8_t)ap_frame_encode(payload, AP_STATUS_LEN, wire);
                ATOMIC_BLOCK(ATOMIC_RESTORESTATE) { tx_push_frame(wire, n, 0); }
                hello_due = 1;
            }
        }
        if (hello_due) {
            hello_due = 0;
            send_hello();
        }
    }
}
