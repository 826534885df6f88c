/* A behavioural model of the ADNS-3080 on its SPI bus, from the datasheet.
 *
 * Pure C with time passed in (nanoseconds): the simavr harness (adns_sim.c) drives it
 * from the simulated clock and the host tests (test_sensor.c) drive it directly.
 *
 * What it models: RESET (pulse width, tOP, inputs inactive for TIN-RST, motion valid
 * after tPU-RESET), the registers the firmware uses (Product_ID 0x17, Inverse 0xF8,
 * Configuration_bits with RES in bit 4, Motion with MOT/OVF/RES, Delta_X/Y, SQUAL,
 * Motion_Clear, Motion_Burst), an internal motion buffer that the 8-bit deltas drain
 * (reads clamp to +-127 and leave the rest, MOT stays set), overflow of that buffer
 * (counts lost, OVF set), and the SPI timings tSRAD, tSRAD-MOT, tSWW/tSWR, tBEXIT.
 * Every count that enters is accounted for: read out, still buffered, lost to overflow,
 * cleared, or arrived while the sensor was not tracking.  Timing violations are counted
 * and the first one is described. */
#ifndef SENSOR_H
#define SENSOR_H
#include <stdint.h>

typedef struct {
    /* parameters */
    int64_t internal_max;  /* internal buffer limit per axis (counts) */
    uint8_t squal;         /* SQUAL while tracking */
    uint8_t absent_miso;   /* what MISO reads when no sensor is there */
    uint64_t byte_ns;      /* duration of one SPI byte on this bus */

    /* state */
    int present;
    int alive;             /* has had a valid reset since it appeared */
    uint64_t reset_rise_ns, inputs_ns, motion_ns;
    int reset_high;
    uint8_t config;        /* Configuration_bits */
    int64_t buf_x, buf_y;
    int ovf;
    uint8_t latched_motion;
    int8_t latched_dx, latched_dy;
    int selected;
    int nbyte;             /* bytes so far in this transaction */
    uint8_t addr;
    int was_burst;
    uint64_t addr_end_ns, deselect_ns, write_end_ns;
    int write_pending;     /* a write happened; the next byte's end must be >= tSWW later */

    /* accounting (sensor axes, counts) */
    int64_t gen_x, gen_y;             /* motion that reached a tracking sensor */
    int64_t read_x, read_y;           /* delivered through Delta_X / Delta_Y */
    int64_t lost_x, lost_y;           /* dropped by buffer overflow */
    int64_t cleared_x, cleared_y;     /* dropped by Motion_Clear or reset */
    int64_t untracked_x, untracked_y; /* motion while absent, in reset or starting */
    uint32_t frames, reads, bursts, resets, spi_bytes, ovf_reads;

    /* datasheet timing violations */
    uint32_t violations;
    char first_violation[160];
} sensor_t;

void sensor_init(sensor_t *s, int present);
/* The sensor appears (power applied: needs a reset) or disappears. */
void sensor_set_present(sensor_t *s, uint64_t t_ns, int present);
/* One sensor frame with (dx, dy) counts of motion at the current resolution. */
void sensor_frame(sensor_t *s, uint64_t t_ns, int32_t dx, int32_t dy);
void sensor_reset_pin(sensor_t *s, uint64_t t_ns, int level);
void sensor_ncs(sensor_t *s, uint64_t t_ns, int level);
/* One SPI byte starting at t_ns: MOSI in, MISO out. */
uint8_t sensor_spi(sensor_t *s, uint64_t t_ns, uint8_t mosi);
/* Resolution now in force (400 or 1600 CPI). */
int sensor_cpi(const sensor_t *s);

#endif
