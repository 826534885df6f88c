#include "accum.h"

void accum_clear(accum_t *a)
{
    a->sx = 0;
    a->sy = 0;
    a->frames = 0;
    a->squal_min = 0xFF;
    a->flags = 0;
}

uint8_t accum_saturated(int8_t dx, int8_t dy)
{
    return dx >= 127 || dx <= -127 || dy >= 127 || dy <= -127;
}

void accum_read(accum_t *a, uint8_t motion, int8_t dx, int8_t dy, uint8_t squal)
{
    if (motion & ADNS_MOT) {
        a->sx += dx;
        a->sy += dy;
    }
    if (motion & ADNS_OVF)
        a->flags |= FLAG_OVERFLOW;
    if (motion & ADNS_RES)
        a->flags |= FLAG_RES1600;
    else
        a->flags &= (uint8_t)~FLAG_RES1600;
    if ((motion & ADNS_MOT) && accum_saturated(dx, dy))
        a->flags |= FLAG_SATURATED;
    if (squal < a->squal_min)
        a->squal_min = squal;
}

void accum_frames(accum_t *a, uint8_t n)
{
    uint16_t room = (uint16_t)(0xFFFFu - a->frames);
    a->frames = (uint16_t)(a->frames + (n < room ? n : room));
}
