/* Consistent Overhead Byte Stuffing: frames on the wire are COBS(body) followed by 0x00.
 * A receiver that sees garbage simply waits for the next 0x00 and starts again, so the
 * stream resynchronises after at most one damaged frame. */
#ifndef COBS_H
#define COBS_H
#include <stdint.h>

/* Encode len (< 254) bytes; out needs len + 1 bytes; returns the encoded length
 * (the 0x00 delimiter is not written). */
uint8_t cobs_encode(const uint8_t *in, uint8_t len, uint8_t *out);

#define COBS_DEC_MAX 24 /* longest body the decoder accepts (host commands are 5 bytes) */

typedef struct {
    uint8_t buf[COBS_DEC_MAX];
    uint8_t len;     /* decoded bytes so far */
    uint8_t left;    /* data bytes left in the current group */
    uint8_t code;    /* code byte of the current group, 0 before the first */
    uint8_t bad;     /* frame overflowed or broke the encoding: drop it at the 0x00 */
} cobs_dec_t;

enum { COBS_MORE = 0, COBS_FRAME = 1, COBS_ERROR = 2 };

void cobs_dec_init(cobs_dec_t *d);
/* Feed one wire byte.  COBS_FRAME: d->buf[0..d->len) holds a complete body (valid until
 * the next call).  COBS_ERROR: a damaged frame ended here and was dropped.  Empty frames
 * (0x00 0x00) are ignored, so a host may send a 0x00 first to flush line noise. */
uint8_t cobs_dec_feed(cobs_dec_t *d, uint8_t byte);

#endif
