/*
 * Host unit test of the firmware's C codec and speed-capture logic (gcc, optionally with
 * -fsanitize=address,undefined). Reads golden vectors as text lines on stdin (written from
 * firmware/test_vectors.json by test/test_firmware_codec.py):
 *   crc <hex|-> <crc>
 *   cobs <raw hex|-> <encoded hex>
 *   sample <seq> <t_us> <i_a> <v_a> <theta> <period> <duty> <flags> <wire hex>
 *   status <rx_frames> <rx_errors> <tx_overflows> <watchdog_trips> <spikes> <angle_errors> <wire hex>
 *   cmd <type> <value> <item> <offset> <wire hex>
 *   invalid <wire hex> <error code>
 * Prints "ok <n>" and exits 0 when every check passes.
 */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "../src/protocol.h"

static int failures, checks;
#define CHECK(cond, ...) do { checks++; if (!(cond)) { failures++; \
    fprintf(stderr, "FAIL %s:%d: ", __FILE__, __LINE__); fprintf(stderr, __VA_ARGS__); \
    fputc('\n', stderr); } } while (0)

static size_t unhex(const char *s, uint8_t *out, size_t cap)
{
    if (strcmp(s, "-") == 0)
        return 0;
    size_t n = strlen(s) / 2;
    if (n > cap) { fprintf(stderr, "vector too long\n"); exit(2); }
    for (size_t i = 0; i < n; i++) { unsigned v; sscanf(s + 2 * i, "%2x", &v); out[i] = (uint8_t)v; }
    return n;
}

static int decode_all(const uint8_t *wire, size_t n, ap_decoder_t *d)
{
    int r = 0;
    for (size_t i = 0; i < n; i++) r = ap_decoder_push(d, wire[i]);
    return r;
}

static void check_wire(const char *name, const uint8_t *payload, size_t plen, const char *hex)
{
    uint8_t want[600], got[AP_MAX_WIRE];
    size_t wn = unhex(hex, want, sizeof want);
    size_t gn = ap_frame_encode(payload, plen, got);
    CHECK(gn == wn && memcmp(got, want, wn) == 0, "%s: encoded frame differs from golden wire", name);
    ap_decoder_t d; ap_decoder_init(&d);
    int r = decode_all(want, wn, &d);
    CHECK(r == 1 && d.payload_len == plen && memcmp(d.payload, payload, plen) == 0,
          "%s: decoder returned %d for the golden wire", name, r);
}

static void test_capture(void)
{
    /* Overflow/capture race: TOV pending + small ICR -> the capture is after the wrap. */
    CHECK(ap_capture_extend(0x0010, 5, 1) == ((6ul << 16) | 0x10), "race low half");
    CHECK(ap_capture_extend(0xFFF0, 5, 1) == ((5ul << 16) | 0xFFF0), "race high half");
    CHECK(ap_capture_extend(0x0010, 5, 0) == ((5ul << 16) | 0x10), "no race");
    ap_speed_t s; ap_speed_init(&s); uint8_t stale;
    CHECK(ap_speed_period(&s, 0, &stale) == 0 && stale, "no edge -> stale");
    /* Edges every 15000 ticks (60 ms) across a 16-bit boundary and the 32-bit wrap. */
    uint32_t t = 0xFFFFFFFFu - 40000u;
    for (int i = 0; i < 6; i++) { ap_speed_edge(&s, t); t += 15000u; }
    CHECK(ap_speed_period(&s, t - 15000u, &stale) == 15000u && !stale, "steady period across wrap");
    /* A glitch 100 ticks after an edge is rejected and does not corrupt the next period. */
    ap_speed_edge(&s, t - 15000u + 100u);
    CHECK(s.spike && s.spikes == 1, "spike flagged");
    ap_speed_edge(&s, t); t += 15000u;
    CHECK(ap_speed_period(&s, t, &stale) == 15000u, "period after spike");
    /* A missed edge (one 30000-tick period) is removed by the median of three. */
    t += 15000u; ap_speed_edge(&s, t);
    CHECK(ap_speed_period(&s, t, &stale) == 15000u, "median removes single outlier, got %lu",
          (unsigned long)ap_speed_period(&s, t, &stale));
    /* Stale after 1 s without edges. */
    CHECK(ap_speed_period(&s, t + AP_CAP_STALE_TICKS, &stale) == 0 && stale, "stale after 1 s");
}

/* AS5040 SSI word as the sensor builds it: angle D9..D0, status bits, then the even-parity bit
 * over the 15 bits before it; bits are assembled one at a time, MSB first, as they arrive. */
static uint16_t as5040_word(uint16_t angle, int ocf, int cof, int lin, int inc, int dec, int flip_parity)
{
    int bits[16], ones = 0;
    for (int i = 0; i < 10; i++) bits[i] = (angle >> (9 - i)) & 1;
    bits[10] = ocf; bits[11] = cof; bits[12] = lin; bits[13] = inc; bits[14] = dec;
    for (int i = 0; i < 15; i++) ones += bits[i];
    bits[15] = (ones & 1) ^ (flip_parity ? 1 : 0);
    uint16_t w = 0;
    for (int i = 0; i < 16; i++) w = (uint16_t)((w << 1) | (uint16_t)bits[i]);
    return w;
}

static void test_as5040(void)
{
    uint16_t angle;
    /* Bit order: D9 is the first bit on the wire = bit 15 of the word. */
    CHECK(as5040_word(512, 1, 0, 0, 0, 0, 0) == 0x8020, "D9 first: got 0x%04x", as5040_word(512, 1, 0, 0, 0, 0, 0));
    CHECK(ap_as5040_decode(0x8020, &angle) == 0 && angle == 512, "angle 512 from 0x8020 (got %u)", angle);
    CHECK(ap_as5040_decode(0x0060, &angle) == 0 && angle == 1, "angle 1 (D0) from 0x0060");
    CHECK(ap_as5040_decode(0xFFE1, &angle) == 0 && angle == 1023, "angle 1023 from 0xFFE1");
    /* Stuck lines: DO high (pull-up, sensor absent) -> COF + field; DO low -> OCF = 0. */
    CHECK(ap_as5040_decode(0xFFFF, &angle) == (AP_SSI_E_COF | AP_SSI_E_FIELD | AP_SSI_W_LIN), "all ones");
    CHECK(ap_as5040_decode(0x0000, &angle) == AP_SSI_E_OCF, "all zeros");
    /* Every angle with every status combination, correct and flipped parity. */
    unsigned n = 0, bad = 0;
    for (uint16_t a = 0; a < 1024; a++) {
        for (int st = 0; st < 32; st++) {
            int ocf = st & 1, cof = (st >> 1) & 1, lin = (st >> 2) & 1, inc = (st >> 3) & 1, dec = (st >> 4) & 1;
            for (int flip = 0; flip < 2; flip++) {
                uint8_t want = (uint8_t)((flip ? AP_SSI_E_PARITY : 0) | (ocf ? 0 : AP_SSI_E_OCF) |
                                         (cof ? AP_SSI_E_COF : 0) | (inc && dec ? AP_SSI_E_FIELD : 0) |
                                         (lin ? AP_SSI_W_LIN : 0));
                uint8_t got = ap_as5040_decode(as5040_word(a, ocf, cof, lin, inc, dec, flip), &angle);
                n++;
                if (got != want || angle != a) bad++;
            }
        }
    }
    CHECK(bad == 0 && n == 65536u, "exhaustive AS5040 words: %u of %u wrong", bad, n);
    /* Any single corrupted bit of a valid word is caught by the parity check. */
    uint16_t ok = as5040_word(300, 1, 0, 0, 0, 0, 0);
    for (int b = 0; b < 16; b++)
        CHECK(ap_as5040_decode((uint16_t)(ok ^ (1u << b)), &angle) & AP_SSI_E_PARITY, "bit %d flip", b);
    /* Valid iff no AP_SSI_INVALID bit: LIN alone is only a warning. */
    CHECK(!(ap_as5040_decode(as5040_word(7, 1, 0, 1, 0, 0, 0), &angle) & AP_SSI_INVALID) && angle == 7,
          "LIN is a warning");
}

static void fuzz_decoder(unsigned long n)
{
    ap_decoder_t d; ap_decoder_init(&d);
    unsigned long x = 12345, frames = 0, errors = 0;
    for (unsigned long i = 0; i < n; i++) {
        x = x * 6364136223846793005ul + 1442695040888963407ul;
        uint8_t b = (uint8_t)(x >> 56);
        if ((x >> 20 & 31) == 0) b = 0;
        int r = ap_decoder_push(&d, b);
        if (r == 1) frames++;
        else if (r < 0) errors++;
    }
    CHECK(errors > 0, "fuzz produced no errors");
    printf("fuzz bytes=%lu frames=%lu errors=%lu\n", n, frames, errors);
}

/* "stream" mode: each stdin line is a hex byte stream; print one line per stream:
 * the hex payloads of the CRC-valid frames (space separated) then "| <errors>". */
static int stream_mode(void)
{
    static char line[1 << 16];
    static uint8_t raw[1 << 15];
    while (fgets(line, sizeof line, stdin)) {
        line[strcspn(line, "\r\n")] = 0;
        size_t n = unhex(line[0] ? line : "-", raw, sizeof raw);
        ap_decoder_t d; ap_decoder_init(&d);
        int errors = 0;
        for (size_t i = 0; i < n; i++) {
            int r = ap_decoder_push(&d, raw[i]);
            if (r < 0) errors++;
            else if (r == 1) {
                for (uint8_t k = 0; k < d.payload_len; k++) printf("%02x", d.payload[k]);
                putchar(' ');
            }
        }
        printf("| %d\n", errors);
    }
    return 0;
}

int main(int argc, char **argv)
{
    char line[4096];
    if (argc > 1 && strcmp(argv[1], "stream") == 0)
        return stream_mode();
    int vectors = 0;
    while (fgets(line, sizeof line, stdin)) {
        char kind[16], a[1200], b[1200];
        uint8_t raw[600], enc[700], out[700], payload[AP_MAX_FRAME];
        if (sscanf(line, "%15s", kind) != 1) continue;
        vectors++;
        if (!strcmp(kind, "crc")) {
            unsigned want; sscanf(line, "%*s %1199s %u", a, &want);
            size_t n = unhex(a, raw, sizeof raw);
            CHECK(ap_crc16(raw, n, 0xFFFF) == want, "crc of %s", a);
        } else if (!strcmp(kind, "cobs")) {
            sscanf(line, "%*s %1199s %1199s", a, b);
            size_t n = unhex(a, raw, sizeof raw), m = unhex(b, enc, sizeof enc);
            size_t e = ap_cobs_encode(raw, n, out);
            CHECK(e == m && memcmp(out, enc, m) == 0, "cobs encode of %zu bytes", n);
            int dn = ap_cobs_decode(enc, m, out, sizeof out);
            CHECK(dn == (int)n && memcmp(out, raw, n) == 0, "cobs decode of %zu bytes: %d", n, dn);
        } else if (!strcmp(kind, "sample")) {
            long f[8];
            sscanf(line, "%*s %ld %ld %ld %ld %ld %ld %ld %ld %1199s", &f[0], &f[1], &f[2], &f[3], &f[4],
                   &f[5], &f[6], &f[7], a);
            ap_sample_t s = {(uint16_t)f[0], (uint32_t)f[1], (int16_t)f[2], (int16_t)f[3],
                             (uint16_t)f[4], (uint32_t)f[5], (uint8_t)f[6], (uint8_t)f[7]};
            ap_sample_pack(&s, payload);
            check_wire("sample", payload, AP_SAMPLE_LEN, a);
        } else if (!strcmp(kind, "status")) {
            long f[6];
            sscanf(line, "%*s %ld %ld %ld %ld %ld %ld %1199s", &f[0], &f[1], &f[2], &f[3], &f[4], &f[5], a);
            ap_status_t s = {(uint16_t)f[0], (uint16_t)f[1], (uint16_t)f[2], (uint16_t)f[3], (uint16_t)f[4],
                             (uint16_t)f[5]};
            ap_status_pack(&s, payload);
            check_wire("status", payload, AP_STATUS_LEN, a);
        } else if (!strcmp(kind, "cmd")) {
            long f[4];
            sscanf(line, "%*s %ld %ld %ld %ld %1199s", &f[0], &f[1], &f[2], &f[3], a);
            ap_command_t c = {(uint8_t)f[0], (uint16_t)f[1], (uint8_t)f[2], (int16_t)f[3]}, p;
            size_t n = ap_command_pack(&c, payload);
            check_wire("cmd", payload, n, a);
            int r = ap_command_parse(payload, n, &p);
            CHECK(r == AP_OK && p.type == c.type && p.value == c.value && p.item == c.item &&
                  p.offset == c.offset, "command 0x%02x parse: %d", c.type, r);
        } else if (!strcmp(kind, "invalid")) {
            int code; sscanf(line, "%*s %1199s %d", a, &code);
            size_t n = unhex(a, raw, sizeof raw);
            ap_decoder_t d; ap_decoder_init(&d);
            int r = decode_all(raw, n, &d);
            if (r == 1) { /* CRC-valid: the error must come from the command/type parser */
                ap_command_t c;
                r = (d.payload[0] == AP_T_SAMPLE) ? (d.payload_len == AP_SAMPLE_LEN ? 1 : AP_E_LENGTH)
                                                   : ap_command_parse(d.payload, d.payload_len, &c);
            }
            CHECK(r == code, "invalid %s: got %d, want %d", a, r, code);
        } else {
            fprintf(stderr, "unknown vector kind %s\n", kind);
            return 2;
        }
    }
    /* Malformed commands. */
    ap_command_t c;
    uint8_t rate0[] = {AP_T_RATE, 0}, cal9[] = {AP_T_CALIBRATE, 9, 0, 0}, duty2[] = {AP_T_DUTY, 1};
    CHECK(ap_command_parse(rate0, 2, &c) == AP_E_VALUE, "rate 0 rejected");
    CHECK(ap_command_parse(cal9, 4, &c) == AP_E_VALUE, "calibration item 9 rejected");
    CHECK(ap_command_parse(duty2, 2, &c) == AP_E_LENGTH, "short duty rejected");
    test_capture();
    test_as5040();
    fuzz_decoder(argc > 1 ? strtoul(argv[1], NULL, 10) : 1000000ul);
    if (vectors == 0) { fprintf(stderr, "no vectors on stdin\n"); return 2; }
    printf("vectors %d checks %d failures %d\n", vectors, checks, failures);
    if (failures) return 1;
    printf("ok %d\n", checks);
    return 0;
}
