/* Microseconds from Timer1 ticks at F_CPU/8 = 921600 Hz (7.3728 MHz crystal).
 *
 * One tick is 625/576 us exactly.  The overflow interrupt adds 65536 ticks =
 * 71111 + 64/576 us to a 32-bit base and carries the 1/576 us remainder, so the clock
 * never drifts from the crystal; a reading adds the current TCNT1 on top.  The 32-bit
 * value wraps after 71.6 minutes; the host unwraps it.  Pure inline maths so that the
 * host tests can check it against exact arithmetic. */
#ifndef USCLOCK_H
#define USCLOCK_H
#include <stdint.h>

#define USCLOCK_NUM 625u
#define USCLOCK_DEN 576u
#define USCLOCK_OVF_US 71111u  /* floor(65536 * 625 / 576) */
#define USCLOCK_OVF_FRAC 64u   /* 65536 * 625 mod 576 */

typedef struct {
    uint32_t base_us;
    uint16_t frac; /* in 1/576 us, < 576 */
} usclock_t;

static inline void usclock_overflow(usclock_t *c)
{
    c->base_us += USCLOCK_OVF_US;
    c->frac += USCLOCK_OVF_FRAC;
    if (c->frac >= USCLOCK_DEN) {
        c->frac -= USCLOCK_DEN;
        c->base_us++;
    }
}

static inline uint32_t usclock_read(const usclock_t *c, uint16_t tcnt)
{
    return c->base_us + ((uint32_t)tcnt * USCLOCK_NUM + c->frac) / USCLOCK_DEN;
}

#endif
