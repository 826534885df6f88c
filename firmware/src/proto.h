/* The serial protocol between the downsampler and the host (docs/adns-protocol.md).
 *
 * Wire frame: COBS(body) 0x00, body = type, payload (little-endian), CRC-16/CCITT-FALSE
 * of type+payload (little-endian).  Every type has one fixed length, which the receiver
 * checks before the CRC.  Pure: builds and parses byte buffers, no I/O. */
#ifndef PROTO_H
#define PROTO_H
#include <stdint.h>

#define PROTO_VERSION 1
#define FW_VERSION_MAJOR 1
#define FW_VERSION_MINOR 0

/* device -> host */
#define PKT_MOTION 0x01
#define PKT_STATUS 0x02
#define PKT_VERSION 0x03
#define PKT_NAK 0x04
/* host -> device */
#define CMD_SET_K 0x81
#define CMD_SET_CPI 0x82
#define CMD_GET_STATUS 0x83
#define CMD_GET_VERSION 0x84

/* payload lengths (without type and CRC) */
#define LEN_MOTION 18
#define LEN_STATUS 21
#define LEN_VERSION 15
#define LEN_NAK 8

/* STATUS.state */
#define STATE_STARTING 0
#define STATE_OK 1
#define STATE_NO_SENSOR 2
/* STATUS.reason */
#define REASON_BOOT 0     /* power-up check done (state says how it went) */
#define REASON_REQUEST 1  /* answer to GET_STATUS */
#define REASON_ACK 2      /* answer to SET_K / SET_CPI: the new settings */
#define REASON_FAULT 3    /* the sensor is missing or stopped answering; retrying */
#define REASON_RECOVERED 4
/* NAK.error */
#define NAK_UNKNOWN 1
#define NAK_LENGTH 2
#define NAK_VALUE 3
#define NAK_CRC 4

#define PROTO_MAX_BODY 24                     /* type + longest payload + CRC */
#define PROTO_MAX_WIRE (PROTO_MAX_BODY + 2)   /* COBS code byte + delimiter */

typedef struct {
    uint16_t seq;
    uint32_t t_us;
    int32_t dx, dy;
    uint16_t frames;
    uint8_t squal_min;
    uint8_t flags;
} motion_pkt_t;

typedef struct {
    uint16_t seq;
    uint32_t t_us;
    uint8_t state, reason;
    uint8_t product_id;  /* last Product_ID read (0x17 for a live ADNS-3080) */
    uint8_t config_bits; /* Configuration_bits read back */
    uint8_t k;
    uint16_t cpi;
    uint16_t poll_us;
    uint16_t overflows;  /* packets with the OVF flag since boot */
    uint16_t rx_errors;  /* host frames dropped (COBS, length or CRC) */
    uint16_t retries;    /* sensor power-up attempts that failed */
} status_pkt_t;

typedef struct {
    uint8_t cmd;
    uint8_t k;
    uint16_t cpi;
} command_t;

/* Build a complete wire frame (including the 0x00); returns its length. */
uint8_t proto_motion(uint8_t *wire, const motion_pkt_t *m);
uint8_t proto_status(uint8_t *wire, const status_pkt_t *s);
uint8_t proto_version(uint8_t *wire, uint16_t seq, uint32_t t_us, uint16_t poll_us,
                      uint32_t f_cpu);
uint8_t proto_nak(uint8_t *wire, uint16_t seq, uint32_t t_us, uint8_t cmd, uint8_t error);

/* Check a decoded host body (type, args, CRC).  Returns 0 and fills *out, or a NAK_*
 * code (out->cmd still names the command when it is known). */
uint8_t proto_parse_command(const uint8_t *body, uint8_t len, command_t *out);

/* Host-side helper (tests, tools): build a command frame; returns its wire length. */
uint8_t proto_command(uint8_t *wire, uint8_t cmd, uint16_t arg);

#endif
