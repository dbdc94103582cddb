/* aeropend serial protocol codec; see protocol.h and firmware/PROTOCOL.md. */
#include "protocol.h"

uint16_t ap_crc16(const uint8_t *data, size_t n, uint16_t crc)
{
    /* CRC-16/CCITT-FALSE, bitwise (small flash footprint; ~25 bytes per frame at 490 Hz). */
    for (size_t i = 0; i < n; i++) {
        crc ^= (uint16_t)((uint16_t)data[i] << 8);
        for (uint8_t b = 0; b < 8; b++)
            crc = (crc & 0x8000u) ? (uint16_t)((crc << 1) ^ 0x1021u) : (uint16_t)(crc << 1);
    }
    return crc;
}

size_t ap_cobs_encode(const uint8_t *in, size_t n, uint8_t *out)
{
    size_t code_idx = 0, o = 1;
    uint8_t code = 1;
    for (size_t i = 0; i < n; i++) {
        if (in[i] == 0) {
            out[code_idx] = code;
            code_idx = o++;
            code = 1;
        } else {
            out[o++] = in[i];
            if (++code == 0xFF) {
                out[code_idx] = code;
                code_idx = o++;
                code = 1;
            }
        }
    }
    out[code_idx] = code;
    return o;
}

int ap_cobs_decode(const uint8_t *in, size_t n, uint8_t *out, size_t cap)
{
    size_t i = 0, o = 0;
    while (i < n) {
        uint8_t code = in[i];
        if (code == 0 || i + code > n)
            return AP_E_COBS;
        for (size_t k = i + 1; k < i + code; k++) {
            if (in[k] == 0 || o >= cap)
                return AP_E_COBS;
            out[o++] = in[k];
        }
        i += code;
        if (code != 0xFF && i < n) {
            if (o >= cap)
                return AP_E_COBS;
            out[o++] = 0;
        }
    }
    return (int)o;
}

size_t ap_frame_encode(const uint8_t *payload, size_t n, uint8_t *out)
{
    uint8_t body[AP_MAX_FRAME];
    if (n == 0 || n + 2 > AP_MAX_FRAME)
        return 0;
    for (size_t i = 0; i < n; i++)
        body[i] = payload[i];
    uint16_t crc = ap_crc16(payload, n, 0xFFFFu);
    body[n] = (uint8_t)(crc & 0xFF);
    body[n + 1] = (uint8_t)(crc >> 8);
    size_t len = ap_cobs_encode(body, n + 2, out);
    out[len++] = 0;
    return len;
}

static void put16(uint8_t *p, uint16_t v) { p[0] = (uint8_t)v; p[1] = (uint8_t)(v >> 8); }
static void put32(uint8_t *p, uint32_t v)
{
    put16(p, (uint16_t)v);
    put16(p + 2, (uint16_t)(v >> 16));
}
static uint16_t get16(const uint8_t *p) { return (uint16_t)(p[0] | ((uint16_t)p[1] << 8)); }

void ap_sample_pack(const ap_sample_t *s, uint8_t out[AP_SAMPLE_LEN])
{
    out[0] = AP_T_SAMPLE;
    put16(out + 1, s->seq);
    put32(out + 3, s->t_us);
    put16(out + 7, (uint16_t)s->i_a);
    put16(out + 9, (uint16_t)s->v_a);
    put16(out + 11, s->theta);
    put32(out + 13, s->period);
    out[17] = s->duty;
    out[18] = s->flags;
}

void ap_sample_pulse_pack(const ap_sample_t *s, uint16_t pulse, uint8_t out[AP_SAMPLE_PULSE_LEN])
{
    ap_sample_pack(s, out); /* same fields up to flags; duty (byte 17) becomes a u16 */
    out[0] = AP_T_SAMPLE_PULSE;
    put16(out + 17, pulse);
    out[19] = s->flags;
}

void ap_hello_pack(const ap_hello_t *h, uint8_t out[AP_HELLO_LEN])
{
    out[0] = AP_T_HELLO;
    out[1] = AP_PROTOCOL_VERSION;
    out[2] = h->actuator;
    out[3] = h->sensor;
    out[4] = h->channels;
    put16(out + 5, h->frame_hz);
    put16(out + 7, h->pulse_min_us);
    put16(out + 9, h->pulse_max_us);
    put16(out + 11, h->arm_ms);
    put16(out + 13, h->silence_ms);
    put32(out + 15, h->counts_per_rev);
}

void ap_status_pack(const ap_status_t *s, uint8_t out[AP_STATUS_LEN])
{
    out[0] = AP_T_STATUS;
    put16(out + 1, s->rx_frames);
    put16(out + 3, s->rx_errors);
    put16(out + 5, s->tx_overflows);
    put16(out + 7, s->watchdog_trips);
    put16(out + 9, s->spikes);
    put16(out + 11, s->angle_errors);
}

int ap_command_parse(const uint8_t *p, size_t n, ap_command_t *cmd)
{
    if (n == 0)
        return AP_E_LENGTH;
    cmd->type = p[0];
    cmd->value = 0;
    cmd->item = 0;
    cmd->offset = 0;
    switch (p[0]) {
    case AP_T_DUTY:
        if (n != 3)
            return AP_E_LENGTH;
        cmd->value = get16(p + 1);
        return AP_OK;
    case AP_T_ENABLE:
        if (n != 2)
            return AP_E_LENGTH;
        cmd->value = p[1] ? 1 : 0;
        return AP_OK;
    case AP_T_RATE:
        if (n != 2)
            return AP_E_LENGTH;
        if (p[1] == 0)
            return AP_E_VALUE;
        cmd->value = p[1];
        return AP_OK;
    case AP_T_PULSE:
        if (n != 3)
            return AP_E_LENGTH;
        cmd->value = get16(p + 1);
        return AP_OK;
    case AP_T_HELLO_REQ:
        if (n != 1)
            return AP_E_LENGTH;
        return AP_OK;
    case AP_T_CALIBRATE:
        if (n != 4)
            return AP_E_LENGTH;
        cmd->item = p[1];
        cmd->offset = (int16_t)get16(p + 2);
        if ((cmd->item != AP_CAL_I_A_OFFSET && cmd->item != AP_CAL_THETA_OFFSET) ||
            cmd->offset <= -1024 || cmd->offset >= 1024)
            return AP_E_VALUE;
        return AP_OK;
    default:
        return AP_E_TYPE;
    }
}

size_t ap_command_pack(const ap_command_t *cmd, uint8_t *out)
{
    out[0] = cmd->type;
    switch (cmd->type) {
    case AP_T_DUTY: put16(out + 1, cmd->value); return 3;
    case AP_T_ENABLE: out[1] = (uint8_t)cmd->value; return 2;
    case AP_T_RATE: out[1] = (uint8_t)cmd->value; return 2;
    case AP_T_CALIBRATE: out[1] = cmd->item; put16(out + 2, (uint16_t)cmd->offset); return 4;
    case AP_T_PULSE: put16(out + 1, cmd->value); return 3;
    default: return 1;
    }
}

void ap_decoder_init(ap_decoder_t *d)
{
    d->len = 0;
    d->overflow = 0;
    d->payload_len = 0;
}

int ap_decoder_push(ap_decoder_t *d, uint8_t byte)
{
    if (byte != 0) {
        if (d->len >= AP_MAX_STUFFED)
            d->overflow = 1;
        else
            d->buf[d->len++] = byte;
        return 0;
    }
    uint8_t len = d->len, over = d->overflow;
    d->len = 0;
    d->overflow = 0;
    if (over)
        return AP_E_OVERSIZE;
    if (len == 0)
        return 0; /* empty frame: ignored */
    uint8_t body[AP_MAX_STUFFED];
    int n = ap_cobs_decode(d->buf, len, body, sizeof body);
    if (n < 0)
        return AP_E_COBS;
    if (n < 3 || n > (int)AP_MAX_FRAME)
        return AP_E_LENGTH;
    uint16_t crc = ap_crc16(body, (size_t)n - 2, 0xFFFFu);
    if (crc != get16(body + n - 2))
        return AP_E_CRC;
    for (int i = 0; i < n - 2; i++)
        d->payload[i] = body[i];
    d->payload_len = (uint8_t)(n - 2);
    return 1;
}

uint32_t ap_capture_extend(uint16_t icr, uint16_t ovf_count, uint8_t tov_pending)
{
    if (tov_pending && icr < 0x8000u)
        ovf_count++;
    return ((uint32_t)ovf_count << 16) | icr;
}

void ap_speed_init(ap_speed_t *s)
{
    s->last_edge = 0;
    s->hist[0] = s->hist[1] = s->hist[2] = 0;
    s->n = 0;
    s->have_edge = 0;
    s->spike = 0;
    s->spikes = 0;
}

void ap_speed_edge(ap_speed_t *s, uint32_t t)
{
    if (!s->have_edge) {
        s->last_edge = t;
        s->have_edge = 1;
        return;
    }
    uint32_t period = t - s->last_edge; /* modular: correct across the 32-bit wrap */
    if (period < AP_CAP_MIN_PERIOD) {
        s->spike = 1;
        s->spikes++;
        return; /* keep last_edge: the next real edge still yields the true period */
    }
    s->spike = 0;
    s->last_edge = t;
    if (period >= AP_CAP_STALE_TICKS) {
        s->n = 0; /* restart after a stop: the long gap is not a speed */
        return;
    }
    s->hist[2] = s->hist[1];
    s->hist[1] = s->hist[0];
    s->hist[0] = period;
    if (s->n < 3)
        s->n++;
}

uint32_t ap_speed_period(const ap_speed_t *s, uint32_t now, uint8_t *stale)
{
    *stale = 0;
    if (!s->have_edge || (uint32_t)(now - s->last_edge) >= AP_CAP_STALE_TICKS) {
        *stale = 1;
        return 0;
    }
    if (s->n == 0)
        return 0;
    if (s->n < 3)
        return s->hist[0];
    uint32_t a = s->hist[0], b = s->hist[1], c = s->hist[2];
    if (a > b) { uint32_t t = a; a = b; b = t; }
    if (b > c) { b = c; }
    return a > b ? a : b; /* median of three */
}

uint8_t ap_as5040_decode(uint16_t word, uint16_t *angle)
{
    uint8_t r = 0, ones = 0;
    for (uint16_t w = word; w; w &= (uint16_t)(w - 1u))
        ones++;
    if (ones & 1u)
        r |= AP_SSI_E_PARITY;
    if (!(word & (1u << 5)))
        r |= AP_SSI_E_OCF;
    if (word & (1u << 4))
        r |= AP_SSI_E_COF;
    if ((word & 0x06u) == 0x06u)
        r |= AP_SSI_E_FIELD;
    if (word & (1u << 3))
        r |= AP_SSI_W_LIN;
    *angle = (uint16_t)(word >> 6);
    return r;
}

int8_t ap_quad_step(uint8_t prev, uint8_t now)
{
    /* index prev << 2 | now; forward (A leads B): 00 -> 01 -> 11 -> 10 -> 00 in (B, A) bits */
    static const int8_t table[16] = {0, 1, -1, AP_QUAD_INVALID, -1, 0, AP_QUAD_INVALID, 1,
                                     1, AP_QUAD_INVALID, 0, -1, AP_QUAD_INVALID, -1, 1, 0};
    return table[((prev & 3u) << 2) | (now & 3u)];
}

uint16_t ap_quad_wrap(uint16_t count, int8_t step, uint16_t cpr)
{
    if (step > 0)
        return (uint16_t)(count + 1u >= cpr ? 0u : count + 1u);
    if (step < 0)
        return (uint16_t)(count == 0u ? cpr - 1u : count - 1u);
    return count;
}
