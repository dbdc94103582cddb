/*
 * aeropend serial protocol codec (see firmware/PROTOCOL.md). Plain C99, no AVR headers, so it
 * compiles for the ATmega2560 and on the host (firmware/test/test_codec.c).
 *
 * Framing: COBS(payload || crc16_le(payload)) || 0x00.
 * CRC-16/CCITT-FALSE: polynomial 0x1021, init 0xFFFF, no reflection, xorout 0
 * (check value 0x29B1 for "123456789").
 */
#ifndef AEROPEND_PROTOCOL_H
#define AEROPEND_PROTOCOL_H

#include <stddef.h>
#include <stdint.h>

#define AP_MAX_FRAME 64u                   /* largest unstuffed frame: payload + CRC */
#define AP_MAX_STUFFED (AP_MAX_FRAME + 2u) /* COBS adds 1 byte per 254 (+1) */
#define AP_MAX_WIRE (AP_MAX_STUFFED + 1u)  /* + delimiter */

#define AP_T_SAMPLE 0x01u
#define AP_T_STATUS 0x02u
#define AP_T_DUTY 0x10u
#define AP_T_ENABLE 0x11u
#define AP_T_RATE 0x12u
#define AP_T_CALIBRATE 0x13u
#define AP_T_HELLO 0x03u       /* MCU -> host: build announcement (actuator, sensor, channels) */
#define AP_T_SAMPLE_PULSE 0x04u /* MCU -> host: SAMPLE of an ESC build (applied pulse, u16) */
#define AP_T_PULSE 0x14u       /* host -> MCU: ESC pulse width [0.5 us] (ESC build only) */
#define AP_T_HELLO_REQ 0x15u   /* host -> MCU: send a HELLO now */

#define AP_SAMPLE_LEN 19u
#define AP_STATUS_LEN 13u
#define AP_SAMPLE_PULSE_LEN 20u
#define AP_HELLO_LEN 19u
#define AP_PROTOCOL_VERSION 2u

/* HELLO actuator and sensor codes, channel bits. */
#define AP_ACT_HBRIDGE 1u
#define AP_ACT_ESC 2u
#define AP_SENSOR_POT 1u      /* angle on the ADC (AS5040 PWM -> RC, or a potentiometer) */
#define AP_SENSOR_SSI 2u      /* AS5040 SSI read-out */
#define AP_SENSOR_ENCODER 3u  /* quadrature encoder on INT2/INT3, decoded x4 */
#define AP_CH_I_A 0x01u
#define AP_CH_V_A 0x02u
#define AP_CH_THETA 0x04u
#define AP_CH_SPEED 0x08u
#define AP_CH_INDEX 0x10u  /* encoder build: the index (Z) is wired; theta is absolute once homed */
/* Wire value of a channel the build does not measure (the host publishes NaN, never 0). */
#define AP_ABSENT_I16 (-32768)
#define AP_ABSENT_U32 0xFFFFFFFFul

#define AP_CAL_I_A_OFFSET 1u
#define AP_CAL_THETA_OFFSET 2u

#define AP_FLAG_ENABLED 0x01u
#define AP_FLAG_WATCHDOG 0x02u
#define AP_FLAG_SPIKE 0x04u
#define AP_FLAG_SPEED_STALE 0x08u
#define AP_FLAG_ANGLE_INVALID 0x10u  /* SSI build: read-out rejected, theta repeats the last valid angle */
#define AP_FLAG_ANGLE_LIN 0x20u      /* SSI build: AS5040 linearity alarm (angle used, may be inaccurate) */
#define AP_FLAG_ANGLE_SSI 0x40u      /* theta comes from the AS5040 SSI read-out (else RC-filtered PWM) */
/* Encoder build: bit4 (AP_FLAG_ANGLE_INVALID) = an impossible quadrature transition (both lines
 * changed between two interrupts) since the previous sample. */
/* Encoder build with an index (AP_CH_INDEX): bit5 (AP_FLAG_ANGLE_UNHOMED) = no index edge since
 * reset, theta counts from the power-up position; bit4 also = the count at an index edge was not
 * the index's count (counts missed since the previous one; re-homed). */
#define AP_FLAG_ANGLE_UNHOMED 0x20u
#define AP_FLAG_ARMING 0x80u         /* ESC build: arming sequence running (minimum pulse, commands held) */

typedef struct {
    uint16_t seq;
    uint32_t t_us;
    int16_t i_a;
    int16_t v_a;
    uint16_t theta;
    uint32_t period;
    uint8_t duty;
    uint8_t flags;
} ap_sample_t;

typedef struct {
    uint8_t actuator;        /* AP_ACT_* */
    uint8_t sensor;          /* AP_SENSOR_* */
    uint8_t channels;        /* AP_CH_* bits of the measured channels */
    uint16_t frame_hz;       /* actuator output frame rate [Hz] (H-bridge PWM 490, ESC 50..490) */
    uint16_t pulse_min_us;   /* ESC: minimum (disarm) pulse [us]; 0 for the H-bridge */
    uint16_t pulse_max_us;   /* ESC: maximum pulse [us]; 0 for the H-bridge */
    uint16_t arm_ms;         /* ESC: minimum pulse held after reset [ms]; 0 for the H-bridge */
    uint16_t silence_ms;     /* command watchdog: output off / minimum pulse after this silence [ms] */
    uint32_t counts_per_rev; /* theta counts per revolution (1024 ADC/SSI, encoder lines x 4) */
} ap_hello_t;

typedef struct {
    uint16_t rx_frames, rx_errors, tx_overflows, watchdog_trips, spikes;
    uint16_t angle_errors; /* rejected AS5040 SSI read-outs (0 in the PWM-interface build) */
} ap_status_t;

typedef struct {
    uint8_t type;    /* AP_T_DUTY, AP_T_ENABLE, AP_T_RATE, AP_T_CALIBRATE */
    uint16_t value;  /* duty value (tau * 65535), enable flag, rate divider */
    uint8_t item;    /* calibration item */
    int16_t offset;  /* calibration offset [counts] */
} ap_command_t;

/* Error codes of ap_command_parse / ap_decoder_push. */
enum { AP_OK = 0, AP_E_COBS = -1, AP_E_CRC = -2, AP_E_LENGTH = -3, AP_E_TYPE = -4,
       AP_E_OVERSIZE = -5, AP_E_VALUE = -6 };

uint16_t ap_crc16(const uint8_t *data, size_t n, uint16_t crc);
/* COBS-encode n bytes into out (room for n + n / 254 + 1); returns the encoded length. */
size_t ap_cobs_encode(const uint8_t *in, size_t n, uint8_t *out);
/* COBS-decode n bytes (no delimiter) into out (cap bytes); returns length or AP_E_COBS. */
int ap_cobs_decode(const uint8_t *in, size_t n, uint8_t *out, size_t cap);
/* Frame a payload: out gets COBS(payload + CRC LE) + 0x00 (room AP_MAX_WIRE); returns the
 * wire length, 0 if the payload is empty or too long. */
size_t ap_frame_encode(const uint8_t *payload, size_t n, uint8_t *out);

void ap_sample_pack(const ap_sample_t *s, uint8_t out[AP_SAMPLE_LEN]);
/* ESC build's sample: the SAMPLE layout with the applied pulse [0.5 us] as u16 in place of the
 * u8 duty (type AP_T_SAMPLE_PULSE, 20 bytes). */
void ap_sample_pulse_pack(const ap_sample_t *s, uint16_t pulse, uint8_t out[AP_SAMPLE_PULSE_LEN]);
void ap_hello_pack(const ap_hello_t *h, uint8_t out[AP_HELLO_LEN]);
void ap_status_pack(const ap_status_t *s, uint8_t out[AP_STATUS_LEN]);
/* Parse a CRC-checked command payload; AP_OK or AP_E_LENGTH / AP_E_TYPE / AP_E_VALUE. */
int ap_command_parse(const uint8_t *payload, size_t n, ap_command_t *cmd);
/* Build a command payload (for host tests); returns its length. */
size_t ap_command_pack(const ap_command_t *cmd, uint8_t *out);

/* Incremental stream decoder: push one byte at a time. */
typedef struct {
    uint8_t buf[AP_MAX_STUFFED];
    uint8_t len;
    uint8_t overflow;
    uint8_t payload[AP_MAX_FRAME];
    uint8_t payload_len;  /* valid after ap_decoder_push returned 1 */
} ap_decoder_t;

void ap_decoder_init(ap_decoder_t *d);
/* Returns 1 when a CRC-valid frame is complete (payload in d->payload, without CRC),
 * 0 when more bytes are needed (or an empty frame), or a negative AP_E_* error for a
 * malformed frame ending at this byte. Never reads or writes out of bounds. */
int ap_decoder_push(ap_decoder_t *d, uint8_t byte);

/* ------------------------------------------------------------------ Timer4 speed capture
 * Pure logic of the input-capture speed measurement (host-testable). Ticks are Timer4 ticks
 * (4 us), extended to 32 bits with a software overflow counter. */
#define AP_CAP_MIN_PERIOD 5000u    /* 20 ms: > 50 rev/s is not physical for this propeller */
#define AP_CAP_STALE_TICKS 250000u /* 1 s without an edge: speed unknown / stopped */

/* 32-bit capture time from the 16-bit ICR value, the overflow count read in the capture ISR
 * and whether an overflow interrupt was pending (TOV flag set) at that moment. If the
 * overflow is pending and the captured value is in the lower half, the capture happened
 * after the wrap: the pending overflow belongs before it. */
uint32_t ap_capture_extend(uint16_t icr, uint16_t ovf_count, uint8_t tov_pending);

typedef struct {
    uint32_t last_edge;   /* extended time of the last accepted edge */
    uint32_t hist[3];     /* last three accepted periods (median-of-3 output) */
    uint8_t n;            /* accepted periods so far (saturates at 3) */
    uint8_t have_edge;
    uint8_t spike;        /* last edge rejected as spike */
    uint16_t spikes;      /* rejected edges (wrapping) */
} ap_speed_t;

void ap_speed_init(ap_speed_t *s);
/* Register a rising edge at extended time t. Edges closer than AP_CAP_MIN_PERIOD to the last
 * accepted edge are rejected as spikes (double triggers, noise) and counted. */
void ap_speed_edge(ap_speed_t *s, uint32_t t);
/* Period to report at time now: median of the last three accepted periods, 0 if fewer than
 * one period is known or no edge for AP_CAP_STALE_TICKS (sets *stale). */
uint32_t ap_speed_period(const ap_speed_t *s, uint32_t now, uint8_t *stale);

/* ------------------------------------------------------------------ AS5040 SSI word
 * 16-bit word as clocked out by the AS5040 (MSB first): bits 15..6 = angle D9..D0, bit 5 OCF
 * (offset compensation finished), bit 4 COF (CORDIC overflow), bit 3 LIN (linearity alarm),
 * bit 2 MagINC, bit 1 MagDEC, bit 0 even parity over bits 15..1 (AS5040 datasheet, SSI). */
#define AP_SSI_E_PARITY 0x01u  /* odd number of ones in the 16-bit word */
#define AP_SSI_E_OCF 0x02u     /* OCF = 0: start-up offset compensation not finished */
#define AP_SSI_E_COF 0x04u     /* COF = 1: CORDIC overflow, D9..D0 invalid */
#define AP_SSI_E_FIELD 0x08u   /* MagINC = MagDEC = 1: magnetic field out of range */
#define AP_SSI_W_LIN 0x10u     /* LIN = 1: linearity alarm (warning only) */
#define AP_SSI_INVALID (AP_SSI_E_PARITY | AP_SSI_E_OCF | AP_SSI_E_COF | AP_SSI_E_FIELD)

/* Check an SSI word; *angle gets D9..D0 (0..1023, 1024 counts per revolution). Returns a mask
 * of AP_SSI_* bits: 0 = valid; any AP_SSI_INVALID bit = reject the angle. */
uint8_t ap_as5040_decode(uint16_t word, uint16_t *angle);

/* ------------------------------------------------------------------ quadrature decoder
 * One x4 decoding step: prev and now are the line states (bit0 = A, bit1 = B). Returns +1 (A
 * leads B), -1, 0 (no change) or AP_QUAD_INVALID (both lines changed: direction unknown). */
#define AP_QUAD_INVALID 2
int8_t ap_quad_step(uint8_t prev, uint8_t now);
/* Advance a position kept in [0, cpr) by step (+1 / -1), wrapping. */
uint16_t ap_quad_wrap(uint16_t count, int8_t step, uint16_t cpr);

#endif
