/* Host tests of the ADNS-3080 model itself, so that the simulation tests of the firmware
 * stand on a checked sensor.  Run by `make sim-test`; exits non-zero on failure. */
#include <stdio.h>

#include "sensor.h"

static int failures, checks;
#define CHECK(c)                                                                   \
    do {                                                                           \
        checks++;                                                                  \
        if (!(c)) {                                                                \
            failures++;                                                            \
            fprintf(stderr, "%s:%d: CHECK failed: %s\n", __FILE__, __LINE__, #c);  \
        }                                                                          \
    } while (0)

#define US 1000ull
#define MS 1000000ull

static uint64_t t;

static uint8_t rd(sensor_t *s, uint8_t reg, uint64_t wait)
{
    sensor_ncs(s, t, 0);
    sensor_spi(s, t, reg);
    t += s->byte_ns + wait;
    uint8_t v = sensor_spi(s, t, 0);
    t += s->byte_ns;
    sensor_ncs(s, t, 1);
    t += 10 * US;
    return v;
}

static void wr(sensor_t *s, uint8_t reg, uint8_t v)
{
    sensor_ncs(s, t, 0);
    sensor_spi(s, t, reg | 0x80);
    t += s->byte_ns;
    sensor_spi(s, t, v);
    t += s->byte_ns;
    sensor_ncs(s, t, 1);
    t += 60 * US;
}

static void burst(sensor_t *s, uint8_t out[4])
{
    sensor_ncs(s, t, 0);
    sensor_spi(s, t, 0x50);
    t += s->byte_ns + 75 * US;
    for (int i = 0; i < 4; i++) {
        out[i] = sensor_spi(s, t, 0);
        t += s->byte_ns;
    }
    sensor_ncs(s, t, 1);
    t += 5 * US;
}

static void power_up(sensor_t *s)
{
    t = 260 * MS;
    sensor_reset_pin(s, t, 1);
    t += 12 * US;
    sensor_reset_pin(s, t, 0);
    t += 600 * US;
}

int main(void)
{
    sensor_t s;
    uint8_t b[4];

    /* no reset yet: registers read as zero and the access is a violation */
    sensor_init(&s, 1);
    t = 300 * MS;
    CHECK(rd(&s, 0x00, 50 * US) == 0x00 && s.violations >= 1);

    /* proper power-up: Product_ID, inverse, default config 400 CPI */
    sensor_init(&s, 1);
    power_up(&s);
    CHECK(rd(&s, 0x00, 50 * US) == 0x17);
    CHECK(rd(&s, 0x3F, 50 * US) == 0xF8);
    CHECK(rd(&s, 0x0A, 50 * US) == 0x09 && sensor_cpi(&s) == 400);
    wr(&s, 0x0A, 0x19);
    CHECK(sensor_cpi(&s) == 1600);
    CHECK(s.violations == 0);

    /* motion before tPU-RESET is not tracked; afterwards it is */
    sensor_frame(&s, t, 5, 5);
    CHECK(s.untracked_x == 5 && s.gen_x == 0);
    t += 40 * MS;
    sensor_frame(&s, t, 100, -300);
    CHECK(s.gen_x == 100 && s.gen_y == -300);
    burst(&s, b);
    CHECK(b[0] == 0x81 && (int8_t)b[1] == 100 && (int8_t)b[2] == -127 && b[3] == 80);
    burst(&s, b); /* the rest of Y drains on the next reads, MOT still set */
    CHECK(b[0] == 0x81 && (int8_t)b[1] == 0 && (int8_t)b[2] == -127);
    burst(&s, b);
    CHECK((int8_t)b[2] == -46);
    burst(&s, b);
    CHECK(b[0] == 0x01 && b[1] == 0 && b[2] == 0);
    CHECK(s.read_x == 100 && s.read_y == -300 && s.violations == 0);

    /* overflow of the internal buffer: counts lost, OVF until a read below full scale */
    s.internal_max = 127;
    sensor_frame(&s, t, 200, 0);
    CHECK(s.lost_x == 73 && s.ovf);
    burst(&s, b);
    CHECK(b[0] & 0x10 && (int8_t)b[1] == 127);
    sensor_frame(&s, t, 3, 0);
    burst(&s, b); /* below full scale: still reports the overflow, then clears it */
    CHECK((b[0] & 0x10) && b[1] == 3);
    burst(&s, b);
    CHECK(!(b[0] & 0x10) && b[1] == 0);
    CHECK(s.gen_x == s.read_x + s.lost_x + s.buf_x);

    /* timing violations are caught */
    uint32_t v = s.violations;
    rd(&s, 0x00, 10 * US); /* tSRAD is 50 us */
    CHECK(s.violations == v + 1);
    rd(&s, 0x02, 60 * US); /* Motion needs 75 us */
    CHECK(s.violations == v + 2);
    sensor_ncs(&s, t, 0);
    sensor_spi(&s, t, 0x50);
    t += s.byte_ns + 80 * US;
    sensor_spi(&s, t, 0);
    sensor_ncs(&s, t, 1);
    t += 1 * US;
    sensor_ncs(&s, t, 0); /* tBEXIT is 4 us */
    sensor_ncs(&s, t, 1);
    CHECK(s.violations == v + 3);

    /* a short reset pulse and one before tOP do not reset */
    sensor_init(&s, 1);
    t = 300 * MS;
    sensor_reset_pin(&s, t, 1);
    sensor_reset_pin(&s, t + 2 * US, 0);
    CHECK(!s.alive && s.violations == 1);
    sensor_init(&s, 1);
    sensor_reset_pin(&s, 1 * MS, 1);
    sensor_reset_pin(&s, 2 * MS, 0);
    CHECK(!s.alive && s.violations == 1);

    /* absent sensor: MISO floats */
    sensor_init(&s, 0);
    power_up(&s);
    CHECK(rd(&s, 0x00, 50 * US) == 0xFF);

    printf("test_sensor: %d checks, %d failures\n", checks, failures);
    return failures ? 1 : 0;
}
