/* Host-gcc unit tests of the firmware's pure modules: CRC, COBS framing, packet layout,
 * command parsing, the motion accumulator and the microsecond clock maths.
 * Built with -fsanitize=address,undefined by `make test`; exits non-zero on any failure. */
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "accum.h"
#include "cobs.h"
#include "crc16.h"
#include "proto.h"
#include "usclock.h"

static int failures, checks;

#define CHECK(cond)                                                                \
    do {                                                                           \
        checks++;                                                                  \
        if (!(cond)) {                                                             \
            failures++;                                                            \
            fprintf(stderr, "%s:%d: CHECK failed: %s\n", __FILE__, __LINE__, #cond); \
        }                                                                          \
    } while (0)

static uint32_t rng = 12345;
static uint32_t rnd(void)
{
    rng ^= rng << 13;
    rng ^= rng >> 17;
    rng ^= rng << 5;
    return rng;
}

/* Feed a wire buffer to a decoder; return the number of complete frames, copying the last. */
static int decode_all(const uint8_t *wire, int n, uint8_t *last, uint8_t *last_len, int *errors)
{
    cobs_dec_t d;
    cobs_dec_init(&d);
    int frames = 0;
    *errors = 0;
    for (int i = 0; i < n; i++) {
        uint8_t r = cobs_dec_feed(&d, wire[i]);
        if (r == COBS_FRAME) {
            frames++;
            memcpy(last, d.buf, d.len);
            *last_len = d.len;
        } else if (r == COBS_ERROR) {
            (*errors)++;
        }
    }
    return frames;
}

static void test_crc(void)
{
    const uint8_t check[] = "123456789";
    CHECK(crc16(check, 9) == 0x29B1); /* the catalogue check value of CRC-16/CCITT-FALSE */
    CHECK(crc16(check, 0) == 0xFFFF);
    uint8_t one = 0;
    CHECK(crc16(&one, 1) == 0xE1F0);
}

static void test_cobs_roundtrip(void)
{
    uint8_t in[40], enc[48], wire[100], out[40], out_len = 0;
    for (int trial = 0; trial < 2000; trial++) {
        uint8_t len = (uint8_t)(1 + rnd() % COBS_DEC_MAX);
        for (int i = 0; i < len; i++)
            in[i] = (rnd() % 3 == 0) ? 0 : (uint8_t)rnd(); /* plenty of zeros */
        uint8_t n = cobs_encode(in, len, enc);
        CHECK(n == len + 1);
        for (int i = 0; i < n; i++)
            CHECK(enc[i] != 0);
        /* garbage, delimiter, frame, delimiter: garbage may decode as some frame (the CRC
         * is what rejects it), but ours always decodes last and intact */
        int w = 0;
        uint8_t garbage = (uint8_t)(rnd() % 5);
        for (int i = 0; i < garbage; i++)
            wire[w++] = (uint8_t)(1 + rnd() % 255);
        wire[w++] = 0;
        memcpy(wire + w, enc, n);
        w += n;
        wire[w++] = 0;
        int errors;
        int frames = decode_all(wire, w, out, &out_len, &errors);
        CHECK(frames >= 1 && frames <= 2);
        CHECK(out_len == len && memcmp(out, in, len) == 0);
    }
}

static void test_cobs_errors(void)
{
    uint8_t out[40], out_len;
    int errors;
    /* code byte promises 5 data bytes but the frame ends after 2 */
    const uint8_t short_group[] = {0x06, 1, 2, 0x00};
    CHECK(decode_all(short_group, 4, out, &out_len, &errors) == 0 && errors == 1);
    /* empty frames are idle line, not errors */
    const uint8_t empties[] = {0, 0, 0};
    CHECK(decode_all(empties, 3, out, &out_len, &errors) == 0 && errors == 0);
    /* longer than the decoder's buffer: dropped, and the next frame still decodes */
    uint8_t wire[80];
    int w = 0;
    wire[w++] = 0x30;
    for (int i = 0; i < 0x2F; i++)
        wire[w++] = 7;
    wire[w++] = 0;
    wire[w++] = 0x02;
    wire[w++] = 9;
    wire[w++] = 0;
    CHECK(decode_all(wire, w, out, &out_len, &errors) == 1 && errors == 1);
    CHECK(out_len == 1 && out[0] == 9);
}

static uint32_t le32(const uint8_t *p) { return p[0] | p[1] << 8 | (uint32_t)p[2] << 16 | (uint32_t)p[3] << 24; }
static uint16_t le16(const uint8_t *p) { return (uint16_t)(p[0] | p[1] << 8); }

static void test_motion_layout(void)
{
    motion_pkt_t m = {.seq = 0xBEEF, .t_us = 0x01020304, .dx = -70000, .dy = 123456,
                      .frames = 12, .squal_min = 0, .flags = FLAG_OVERFLOW | FLAG_BOOT};
    uint8_t wire[PROTO_MAX_WIRE], body[40], len;
    uint8_t n = proto_motion(wire, &m);
    CHECK(n <= PROTO_MAX_WIRE && wire[n - 1] == 0);
    int errors;
    CHECK(decode_all(wire, n, body, &len, &errors) == 1);
    CHECK(len == 1 + LEN_MOTION + 2);
    CHECK(body[0] == PKT_MOTION);
    CHECK(le16(body + 1) == 0xBEEF);
    CHECK(le32(body + 3) == 0x01020304);
    CHECK((int32_t)le32(body + 7) == -70000);
    CHECK((int32_t)le32(body + 11) == 123456);
    CHECK(le16(body + 15) == 12);
    CHECK(body[17] == 0 && body[18] == (FLAG_OVERFLOW | FLAG_BOOT));
    CHECK(le16(body + 19) == crc16(body, 19));
}

static void test_other_layouts(void)
{
    uint8_t wire[PROTO_MAX_WIRE], body[40], len;
    int errors;
    status_pkt_t s = {.seq = 1, .t_us = 2, .state = STATE_NO_SENSOR, .reason = REASON_FAULT,
                      .product_id = 0xFF, .config_bits = 0x19, .k = 12, .cpi = 1600,
                      .poll_us = 1250, .overflows = 3, .rx_errors = 4, .retries = 5};
    uint8_t n = proto_status(wire, &s);
    CHECK(n <= PROTO_MAX_WIRE);
    CHECK(decode_all(wire, n, body, &len, &errors) == 1 && len == 1 + LEN_STATUS + 2);
    CHECK(body[0] == PKT_STATUS && body[7] == STATE_NO_SENSOR && body[8] == REASON_FAULT);
    CHECK(body[9] == 0xFF && body[10] == 0x19 && body[11] == 12 && le16(body + 12) == 1600);
    CHECK(le16(body + 14) == 1250 && le16(body + 20) == 5);
    CHECK(le16(body + len - 2) == crc16(body, (uint8_t)(len - 2)));

    n = proto_version(wire, 7, 8, 1250, 7372800UL);
    CHECK(decode_all(wire, n, body, &len, &errors) == 1 && len == 1 + LEN_VERSION + 2);
    CHECK(body[0] == PKT_VERSION && body[7] == PROTO_VERSION && le32(body + 12) == 7372800UL);

    n = proto_nak(wire, 9, 10, CMD_SET_K, NAK_VALUE);
    CHECK(decode_all(wire, n, body, &len, &errors) == 1 && len == 1 + LEN_NAK + 2);
    CHECK(body[0] == PKT_NAK && body[7] == CMD_SET_K && body[8] == NAK_VALUE);
}

static uint8_t parse_wire(const uint8_t *wire, uint8_t n, command_t *c)
{
    uint8_t body[40], len;
    int errors;
    if (decode_all(wire, n, body, &len, &errors) != 1)
        return 0xEE;
    return proto_parse_command(body, len, c);
}

static void test_commands(void)
{
    uint8_t wire[PROTO_MAX_WIRE];
    command_t c;
    uint8_t n = proto_command(wire, CMD_SET_K, 5);
    CHECK(parse_wire(wire, n, &c) == 0 && c.cmd == CMD_SET_K && c.k == 5);
    n = proto_command(wire, CMD_SET_K, 0);
    CHECK(parse_wire(wire, n, &c) == NAK_VALUE);
    n = proto_command(wire, CMD_SET_CPI, 400);
    CHECK(parse_wire(wire, n, &c) == 0 && c.cpi == 400);
    n = proto_command(wire, CMD_SET_CPI, 800);
    CHECK(parse_wire(wire, n, &c) == NAK_VALUE);
    n = proto_command(wire, CMD_GET_STATUS, 0);
    CHECK(parse_wire(wire, n, &c) == 0 && c.cmd == CMD_GET_STATUS);
    n = proto_command(wire, CMD_GET_VERSION, 0);
    CHECK(parse_wire(wire, n, &c) == 0 && c.cmd == CMD_GET_VERSION);
    n = proto_command(wire, 0x99, 0);
    CHECK(parse_wire(wire, n, &c) == NAK_UNKNOWN);

    /* every single-bit flip of a SET_K frame is refused (CRC, length or framing) */
    uint8_t good[PROTO_MAX_WIRE];
    uint8_t gn = proto_command(good, CMD_SET_K, 12);
    int accepted_bad = 0;
    for (int byte = 0; byte < gn - 1; byte++) {
        for (int bit = 0; bit < 8; bit++) {
            memcpy(wire, good, gn);
            wire[byte] ^= (uint8_t)(1 << bit);
            uint8_t r = parse_wire(wire, gn, &c);
            if (r == 0 && !(c.cmd == CMD_SET_K && c.k == 12))
                accepted_bad++;
        }
    }
    CHECK(accepted_bad == 0);

    /* wrong lengths with a right CRC */
    uint8_t body[8] = {CMD_GET_STATUS, 1};
    uint16_t crc = crc16(body, 2);
    body[2] = (uint8_t)crc;
    body[3] = (uint8_t)(crc >> 8);
    CHECK(proto_parse_command(body, 4, &c) == NAK_LENGTH);
    CHECK(proto_parse_command(body, 2, &c) == NAK_LENGTH);
}

static void test_accum(void)
{
    accum_t a;
    accum_clear(&a);
    CHECK(a.frames == 0 && a.squal_min == 0xFF && a.sx == 0 && a.flags == 0);
    /* deltas count only with MOT set */
    accum_read(&a, 0x00, 5, 5, 80);
    CHECK(a.sx == 0 && a.sy == 0 && a.squal_min == 80);
    accum_read(&a, ADNS_MOT | ADNS_RES, 3, -4, 60);
    accum_frames(&a, 1);
    CHECK(a.sx == 3 && a.sy == -4 && a.frames == 1 && a.squal_min == 60);
    CHECK(a.flags & FLAG_RES1600);
    accum_read(&a, ADNS_MOT, 1, 1, 70); /* RES cleared: 400 CPI now */
    CHECK(!(a.flags & FLAG_RES1600) && a.squal_min == 60);
    accum_read(&a, ADNS_MOT | ADNS_OVF, 127, 0, 70);
    CHECK(a.flags & FLAG_OVERFLOW && a.flags & FLAG_SATURATED);
    /* 32-bit sums: 1000 full-scale reads pass 16 bits without wrapping */
    accum_clear(&a);
    for (int i = 0; i < 1000; i++) {
        accum_read(&a, ADNS_MOT, 127, -128, 50);
        accum_frames(&a, 1);
    }
    CHECK(a.sx == 127000 && a.sy == -128000 && a.frames == 1000);
    CHECK(accum_saturated(127, 0) && accum_saturated(0, -128) && accum_saturated(-127, 3));
    CHECK(!accum_saturated(126, -126));
    /* the frame count saturates instead of wrapping */
    a.frames = 0xFFFE;
    accum_frames(&a, 1);
    accum_frames(&a, 1);
    CHECK(a.frames == 0xFFFF);
    /* merged ticks count as the periods they covered */
    accum_clear(&a);
    accum_frames(&a, 3);
    accum_frames(&a, 1);
    CHECK(a.frames == 4);
}

static void test_usclock(void)
{
    usclock_t c = {0, 0};
    uint64_t ticks = 0;
    uint32_t prev = 0;
    for (int ovf = 0; ovf < 70000; ovf++) { /* 70000 * 65536 ticks: past the 32-bit wrap */
        for (int probe = 0; probe < 3; probe++) {
            uint16_t t = probe == 0 ? 0 : probe == 1 ? 0xFFFF : (uint16_t)rnd();
            uint64_t exact = ((ticks + t) * 625u) / 576u;
            uint32_t got = usclock_read(&c, t);
            CHECK(got == (uint32_t)exact);
            if (probe == 0) {
                CHECK((uint32_t)(got - prev) < 80000u); /* monotonic modulo 2^32 */
                prev = got;
            }
        }
        usclock_overflow(&c);
        ticks += 65536;
    }
}

int main(void)
{
    test_crc();
    test_cobs_roundtrip();
    test_cobs_errors();
    test_motion_layout();
    test_other_layouts();
    test_commands();
    test_accum();
    test_usclock();
    printf("test_host: %d checks, %d failures\n", checks, failures);
    return failures ? 1 : 0;
}
