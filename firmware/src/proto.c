#include "proto.h"
#include "cobs.h"
#include "crc16.h"

typedef struct {
    uint8_t b[PROTO_MAX_BODY];
    uint8_t n;
} body_t;

static void u8(body_t *p, uint8_t v) { p->b[p->n++] = v; }
static void u16(body_t *p, uint16_t v) { u8(p, (uint8_t)v); u8(p, (uint8_t)(v >> 8)); }
static void u32(body_t *p, uint32_t v) { u16(p, (uint16_t)v); u16(p, (uint16_t)(v >> 16)); }

static uint8_t finish(body_t *p, uint8_t *wire)
{
    uint16_t crc = crc16(p->b, p->n);
    u16(p, crc);
    uint8_t n = cobs_encode(p->b, p->n, wire);
    wire[n++] = 0;
    return n;
}

uint8_t proto_motion(uint8_t *wire, const motion_pkt_t *m)
{
    body_t p = {.n = 0};
    u8(&p, PKT_MOTION);
    u16(&p, m->seq);
    u32(&p, m->t_us);
    u32(&p, (uint32_t)m->dx);
    u32(&p, (uint32_t)m->dy);
    u16(&p, m->frames);
    u8(&p, m->squal_min);
    u8(&p, m->flags);
    return finish(&p, wire);
}

uint8_t proto_status(uint8_t *wire, const status_pkt_t *s)
{
    body_t p = {.n = 0};
    u8(&p, PKT_STATUS);
    u16(&p, s->seq);
    u32(&p, s->t_us);
    u8(&p, s->state);
    u8(&p, s->reason);
    u8(&p, s->product_id);
    u8(&p, s->config_bits);
    u8(&p, s->k);
    u16(&p, s->cpi);
    u16(&p, s->poll_us);
    u16(&p, s->overflows);
    u16(&p, s->rx_errors);
    u16(&p, s->retries);
    return finish(&p, wire);
}

uint8_t proto_version(uint8_t *wire, uint16_t seq, uint32_t t_us, uint16_t poll_us,
                      uint32_t f_cpu)
{
    body_t p = {.n = 0};
    u8(&p, PKT_VERSION);
    u16(&p, seq);
    u32(&p, t_us);
    u8(&p, PROTO_VERSION);
    u8(&p, FW_VERSION_MAJOR);
    u8(&p, FW_VERSION_MINOR);
    u16(&p, poll_us);
    u32(&p, f_cpu);
    return finish(&p, wire);
}

uint8_t proto_nak(uint8_t *wire, uint16_t seq, uint32_t t_us, uint8_t cmd, uint8_t error)
{
    body_t p = {.n = 0};
    u8(&p, PKT_NAK);
    u16(&p, seq);
    u32(&p, t_us);
    u8(&p, cmd);
    u8(&p, error);
    return finish(&p, wire);
}

uint8_t proto_parse_command(const uint8_t *body, uint8_t len, command_t *out)
{
    out->cmd = len ? body[0] : 0;
    out->k = 0;
    out->cpi = 0;
    if (len < 3)
        return NAK_LENGTH;
    uint16_t crc = (uint16_t)(body[len - 2] | (body[len - 1] << 8));
    if (crc16(body, (uint8_t)(len - 2)) != crc)
        return NAK_CRC;
    uint8_t args = (uint8_t)(len - 3);
    switch (out->cmd) {
    case CMD_SET_K:
        if (args != 1)
            return NAK_LENGTH;
        out->k = body[1];
        return out->k ? 0 : NAK_VALUE;
    case CMD_SET_CPI:
        if (args != 2)
            return NAK_LENGTH;
        out->cpi = (uint16_t)(body[1] | (body[2] << 8));
        return (out->cpi == 400 || out->cpi == 1600) ? 0 : NAK_VALUE;
    case CMD_GET_STATUS:
    case CMD_GET_VERSION:
        return args == 0 ? 0 : NAK_LENGTH;
    default:
        return NAK_UNKNOWN;
    }
}

uint8_t proto_command(uint8_t *wire, uint8_t cmd, uint16_t arg)
{
    body_t p = {.n = 0};
    u8(&p, cmd);
    if (cmd == CMD_SET_K)
        u8(&p, (uint8_t)arg);
    else if (cmd == CMD_SET_CPI)
        u16(&p, arg);
    return finish(&p, wire);
}
