#include "cobs.h"

uint8_t cobs_encode(const uint8_t *in, uint8_t len, uint8_t *out)
{
    uint8_t code_at = 0, code = 1, o = 1;
    for (uint8_t i = 0; i < len; i++) {
        if (in[i] == 0) {
            out[code_at] = code;
            code_at = o++;
            code = 1;
        } else {
            out[o++] = in[i];
            code++;
            /* bodies are < 254 bytes, so a group never reaches the 0xFF length limit */
        }
    }
    out[code_at] = code;
    return o;
}

void cobs_dec_init(cobs_dec_t *d)
{
    d->len = 0;
    d->left = 0;
    d->code = 0;
    d->bad = 0;
}

static void put(cobs_dec_t *d, uint8_t b)
{
    if (d->len < COBS_DEC_MAX)
        d->buf[d->len++] = b;
    else
        d->bad = 1;
}

uint8_t cobs_dec_feed(cobs_dec_t *d, uint8_t byte)
{
    if (byte == 0) {
        uint8_t result;
        if (d->code == 0 && !d->bad)
            result = COBS_MORE; /* empty frame: idle line or a flush */
        else if (d->bad || d->left != 0)
            result = COBS_ERROR;
        else
            result = COBS_FRAME;
        d->left = 0;
        d->code = 0;
        d->bad = 0;
        if (result != COBS_FRAME)
            d->len = 0;
        return result;
    }
    if (d->code == 0 && d->left == 0 && d->len != 0) {
        /* first byte after a delivered frame: start a fresh body */
        d->len = 0;
    }
    if (d->left == 0) {
        /* a code byte: the previous group (if any, and not a full 0xFF one) ended in 0 */
        if (d->code != 0 && d->code != 0xFF)
            put(d, 0);
        d->code = byte;
        d->left = (uint8_t)(byte - 1);
    } else {
        put(d, byte);
        d->left--;
    }
    return COBS_MORE;
}
