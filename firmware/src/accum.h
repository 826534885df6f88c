/* Sums of ADNS-3080 motion reads between two packets.  Pure: no I/O, host-testable.
 *
 * One "frame" is one period of the firmware's poll timer; normally one poll.  A poll
 * may need several motion-burst reads when a delta comes back at full scale (the sensor
 * keeps the rest in its internal buffer and leaves MOT set, datasheet "Notes for
 * Motion" 3); all of them land in the same frame. */
#ifndef ACCUM_H
#define ACCUM_H
#include <stdint.h>

/* Motion register (0x02) bits, ADNS-3080 datasheet p. 24 */
#define ADNS_MOT 0x80
#define ADNS_OVF 0x10
#define ADNS_RES 0x01
#define ADNS_MOTION_RESERVED 0x6E /* read as 0 from a live sensor */

/* MOTION packet flags (see docs/adns-protocol.md) */
#define FLAG_OVERFLOW 0x01  /* the sensor set OVF: counts were lost inside the sensor */
#define FLAG_FAULT 0x02     /* the sensor stopped answering during this packet */
#define FLAG_BOOT 0x04      /* first MOTION packet since the firmware started */
#define FLAG_DELAYED 0x08   /* frames > K: UART busy, K lowered, or a poll overran */
#define FLAG_RES1600 0x10   /* the sensor's RES bit said 1600 CPI in the last read */
#define FLAG_SATURATED 0x20 /* a delta read at full scale and was drained by re-reading */

#define DRAIN_MAX_READS 8 /* motion reads per frame at most (bounds |sum| <= 8*128*frames) */

typedef struct {
    int32_t sx, sy;     /* sums of Delta_X and Delta_Y (sensor axes, counts) */
    uint16_t frames;    /* polls in this packet */
    uint8_t squal_min;  /* minimum SQUAL seen (0xFF when no read yet) */
    uint8_t flags;      /* FLAG_* */
} accum_t;

void accum_clear(accum_t *a);
/* Add one motion-burst read; motion is the Motion register, dx/dy the raw deltas. */
void accum_read(accum_t *a, uint8_t motion, int8_t dx, int8_t dy, uint8_t squal);
/* Close n frames: one poll that covered n poll periods (n > 1 when a poll overran its
 * period and ticks were merged), so that frames always measure elapsed time. */
void accum_frames(accum_t *a, uint8_t n);
/* Does a read at this delta need another read to drain the sensor's buffer? */
uint8_t accum_saturated(int8_t dx, int8_t dy);

#endif
