#include "sensor.h"

#include <stdarg.h>
#include <stdio.h>
#include <string.h>

/* datasheet timings, ns */
#define T_OP 250000000ull
#define T_PW_RESET 10000ull
#define T_IN_RST 500000ull
#define T_PU_RESET 35000000ull
#define T_SRAD 50000ull
#define T_SRAD_MOT 75000ull
#define T_SWW 50000ull
#define T_BEXIT 4000ull

#define CONFIG_DEFAULT 0x09
#define CONFIG_RES 0x10

static void violation(sensor_t *s, const char *fmt, ...)
{
    if (s->violations++ == 0) {
        va_list ap;
        va_start(ap, fmt);
        vsnprintf(s->first_violation, sizeof s->first_violation, fmt, ap);
        va_end(ap);
    }
}

void sensor_init(sensor_t *s, int present)
{
    memset(s, 0, sizeof *s);
    s->internal_max = 2047;
    s->squal = 80;
    s->absent_miso = 0xFF;
    s->byte_ns = 100000; /* simavr 1.6: 100 us a byte */
    s->present = present;
    s->config = CONFIG_DEFAULT;
}

int sensor_cpi(const sensor_t *s) { return (s->config & CONFIG_RES) ? 1600 : 400; }

static int tracking(const sensor_t *s, uint64_t t)
{
    return s->present && s->alive && !s->reset_high && t >= s->motion_ns;
}

static int inputs_active(const sensor_t *s, uint64_t t)
{
    return s->present && s->alive && !s->reset_high && t >= s->inputs_ns;
}

static void drop_buffers(sensor_t *s)
{
    s->cleared_x += s->buf_x;
    s->cleared_y += s->buf_y;
    s->buf_x = s->buf_y = 0;
    s->ovf = 0;
    s->latched_motion = 0;
    s->latched_dx = s->latched_dy = 0;
}

void sensor_set_present(sensor_t *s, uint64_t t_ns, int present)
{
    (void)t_ns;
    if (present == s->present)
        return;
    s->present = present;
    s->alive = 0; /* a sensor that (re)appears has just been powered: it needs a reset */
    drop_buffers(s);
    s->config = CONFIG_DEFAULT;
}

static void add_axis(sensor_t *s, int64_t *buf, int64_t *lost, int32_t d)
{
    int64_t v = *buf + d;
    if (v > s->internal_max) {
        *lost += v - s->internal_max;
        v = s->internal_max;
        s->ovf = 1;
    } else if (v < -s->internal_max) {
        *lost += v + s->internal_max;
        v = -s->internal_max;
        s->ovf = 1;
    }
    *buf = v;
}

void sensor_frame(sensor_t *s, uint64_t t_ns, int32_t dx, int32_t dy)
{
    s->frames++;
    if (!tracking(s, t_ns)) {
        s->untracked_x += dx;
        s->untracked_y += dy;
        return;
    }
    s->gen_x += dx;
    s->gen_y += dy;
    add_axis(s, &s->buf_x, &s->lost_x, dx);
    add_axis(s, &s->buf_y, &s->lost_y, dy);
}

void sensor_reset_pin(sensor_t *s, uint64_t t_ns, int level)
{
    level = level != 0;
    if (level == s->reset_high)
        return;
    s->reset_high = level;
    if (level) {
        s->reset_rise_ns = t_ns;
        return;
    }
    if (!s->present)
        return;
    if (t_ns - s->reset_rise_ns < T_PW_RESET) {
        violation(s, "RESET pulse of %llu ns is shorter than tPW-RESET (10 us)",
                  (unsigned long long)(t_ns - s->reset_rise_ns));
        return;
    }
    if (s->reset_rise_ns < T_OP) {
        violation(s, "RESET pulse at %llu us, before tOP (250 ms after power)",
                  (unsigned long long)(s->reset_rise_ns / 1000));
        return;
    }
    s->resets++;
    s->alive = 1;
    drop_buffers(s);
    s->config = CONFIG_DEFAULT;
    s->inputs_ns = t_ns + T_IN_RST;
    s->motion_ns = t_ns + T_PU_RESET;
}

void sensor_ncs(sensor_t *s, uint64_t t_ns, int level)
{
    level = level != 0;
    if (level == !s->selected)
        return;
    if (!level) {
        if (s->was_burst && t_ns - s->deselect_ns < T_BEXIT)
            violation(s, "NCS high for %llu ns after a burst, under tBEXIT (4 us)",
                      (unsigned long long)(t_ns - s->deselect_ns));
        s->selected = 1;
        s->nbyte = 0;
        s->was_burst = 0;
    } else {
        s->selected = 0;
        s->deselect_ns = t_ns;
    }
}

/* Reading Motion (or starting a burst) freezes the deltas: clamp to 8 bits, leave the
 * rest in the buffer.  OVF clears once a read is not at full scale (datasheet p. 24). */
static void latch_motion(sensor_t *s)
{
    int64_t dx = s->buf_x, dy = s->buf_y;
    if (dx > 127) dx = 127;
    if (dx < -127) dx = -127;
    if (dy > 127) dy = 127;
    if (dy < -127) dy = -127;
    uint8_t m = 0;
    if (s->buf_x || s->buf_y)
        m |= 0x80;
    if (s->ovf) {
        m |= 0x10;
        s->ovf_reads++;
    }
    if (s->config & CONFIG_RES)
        m |= 0x01;
    s->buf_x -= dx;
    s->buf_y -= dy;
    s->read_x += dx;
    s->read_y += dy;
    s->latched_motion = m;
    s->latched_dx = (int8_t)dx;
    s->latched_dy = (int8_t)dy;
    s->reads++;
    if (dx != 127 && dx != -127 && dy != 127 && dy != -127)
        s->ovf = 0;
}

static uint8_t read_reg(sensor_t *s, uint8_t addr)
{
    uint8_t v;
    switch (addr) {
    case 0x00: return 0x17;
    case 0x01: return 0x01;
    case 0x02: return s->latched_motion;
    case 0x03: v = (uint8_t)s->latched_dx; s->latched_dx = 0; return v;
    case 0x04: v = (uint8_t)s->latched_dy; s->latched_dy = 0; return v;
    case 0x05: return s->squal;
    case 0x0A: return s->config;
    case 0x3F: return 0xF8;
    default: return 0;
    }
}

static void write_reg(sensor_t *s, uint8_t addr, uint8_t v)
{
    if (addr == 0x0A) {
        if (v & 0x80)
            violation(s, "Configuration_bits written with bit 7 set (0x%02x)", v);
        s->config = v & 0x7F;
    } else if (addr == 0x12) {
        drop_buffers(s);
    }
}

uint8_t sensor_spi(sensor_t *s, uint64_t t_ns, uint8_t mosi)
{
    s->spi_bytes++;
    uint64_t end = t_ns + s->byte_ns;
    if (!s->selected)
        return s->absent_miso; /* not addressed: MISO is tri-stated */
    if (!s->present)
        return s->absent_miso;
    if (!inputs_active(s, t_ns)) {
        if (s->alive)
            violation(s, "SPI access %llu us after RESET, before TIN-RST (500 us)",
                      (unsigned long long)((t_ns + T_IN_RST - s->inputs_ns) / 1000));
        else
            violation(s, "SPI access at %llu us before any valid RESET pulse",
                      (unsigned long long)(t_ns / 1000));
        return 0x00;
    }
    if (s->write_pending && end - s->write_end_ns < T_SWW) {
        violation(s, "%llu ns between a write and the next byte, under tSWW/tSWR (50 us)",
                  (unsigned long long)(end - s->write_end_ns));
    }
    s->write_pending = 0;
    int n = s->nbyte++;
    if (n == 0) {
        s->addr = mosi;
        s->addr_end_ns = end;
        if (mosi == 0x50) {
            s->was_burst = 1;
            s->bursts++;
            latch_motion(s);
        } else if (mosi == 0x02) {
            latch_motion(s);
        }
        return 0x00;
    }
    if (s->addr & 0x80) {
        if (n == 1) {
            write_reg(s, s->addr & 0x7F, mosi);
            s->write_end_ns = end;
            s->write_pending = 1;
        }
        return 0x00;
    }
    if (n == 1) {
        uint64_t need = (s->addr == 0x50 || s->addr == 0x02) ? T_SRAD_MOT : T_SRAD;
        if (t_ns - s->addr_end_ns < need)
            violation(s, "read of 0x%02x after %llu ns, under tSRAD (%llu us)", s->addr,
                      (unsigned long long)(t_ns - s->addr_end_ns),
                      (unsigned long long)(need / 1000));
    }
    if (s->addr == 0x50) {
        switch (n) {
        case 1: return s->latched_motion;
        case 2: return (uint8_t)s->latched_dx;
        case 3: return (uint8_t)s->latched_dy;
        case 4: return s->squal;
        case 5: return 0x00;  /* Shutter_Upper */
        case 6: return 0x85;  /* Shutter_Lower */
        case 7: return 0x3F;  /* Maximum_Pixel */
        default: return 0x00;
        }
    }
    return n == 1 ? read_reg(s, s->addr) : 0x00;
}
