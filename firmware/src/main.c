/* ADNS-3080 downsampler for the ATmega8 (mousedom issue 6).
 *
 * Polls the sensor every POLL_US with a motion burst, sums the deltas of K polls in 32
 * bits and sends one MOTION packet per K polls, stamped with its own microsecond clock.
 * Power-up follows the datasheet (wait tOP, RESET pulse, wait for the inputs, check
 * Product_ID and Inverse_Product_ID, set the resolution, wait for valid motion data); a
 * missing sensor is reported in a STATUS packet and tried again every second.  The main
 * loop is a small state machine driven by the poll tick, so host commands are served in
 * every state and nothing ever blocks for longer than one SPI transaction. */
#include <avr/interrupt.h>
#include <avr/io.h>
#include <avr/sleep.h>

#include "accum.h"
#include "adns3080.h"
#include "board.h"
#include "cobs.h"
#include "proto.h"
#include "uart.h"
#include "usclock.h"

/* ---------------------------------------------------------------- clock and poll tick */

static volatile usclock_t clk;
static volatile uint8_t tick_pending;

ISR(TIMER1_OVF_vect) { usclock_overflow((usclock_t *)&clk); }

ISR(TIMER1_COMPA_vect)
{
    OCR1A += POLL_TICKS;
    if (tick_pending != 0xFF)
        tick_pending++; /* a counter: a poll that overruns still accounts for the time */
}

static uint32_t clock_us(void)
{
    uint8_t s = SREG;
    cli();
    uint16_t t = TCNT1;
    usclock_t c = *(usclock_t *)&clk;
    if ((TIFR & (1 << TOV1)) && t < 0x8000u)
        usclock_overflow(&c); /* the overflow happened but its interrupt has not run yet */
    SREG = s;
    return usclock_read(&c, t);
}

static uint8_t reached(uint32_t now, uint32_t deadline) { return (int32_t)(now - deadline) >= 0; }

static void timer_init(void)
{
    TCCR1A = 0;
    TCCR1B = (1 << CS11); /* F_CPU/8, free running */
    OCR1A = POLL_TICKS;
    TIMSK |= (1 << OCIE1A) | (1 << TOIE1);
}

/* ---------------------------------------------------------------- state */

enum { S_POWER, S_RESET_WAIT, S_STARTUP, S_RUN, S_RETRY };

static uint8_t state = S_POWER;
static uint32_t deadline;
static uint32_t reset_at;
static uint8_t k = DEFAULT_K;
static uint16_t cpi = DEFAULT_CPI;
static uint8_t cpi_pending; /* apply at the next packet boundary */
static uint8_t ever_ok, boot_flag = FLAG_BOOT;
static uint8_t product_id, config_bits;
static uint16_t seq, overflows, rx_errors, retries;
static accum_t acc;
static uint32_t last_read_us;
static cobs_dec_t rx;

/* replies waiting for room in the UART ring */
#define NO_REASON 0xFF
static uint8_t pending_status = NO_REASON;
static uint8_t pending_version;
static uint8_t pending_nak_cmd, pending_nak_err;

static uint8_t sensor_state(void)
{
    if (state == S_RUN)
        return STATE_OK;
    if (state == S_RETRY)
        return STATE_NO_SENSOR;
    return STATE_STARTING;
}

/* ---------------------------------------------------------------- output */

static uint8_t wire[PROTO_MAX_WIRE];

static uint8_t send(uint8_t n)
{
    if (uart_tx_free() < n)
        return 0;
    uart_write(wire, n);
    seq++;
    return 1;
}

static void flush_replies(void)
{
    if (pending_status != NO_REASON) {
        status_pkt_t s = {
            .seq = seq,
            .t_us = clock_us(),
            .state = sensor_state(),
            .reason = pending_status,
            .product_id = product_id,
            .config_bits = config_bits,
            .k = k,
            .cpi = cpi,
            .poll_us = POLL_US,
            .overflows = overflows,
            .rx_errors = (uint16_t)(rx_errors + uart_rx_overruns()),
            .retries = retries,
        };
        if (!send(proto_status(wire, &s)))
            return;
        pending_status = NO_REASON;
    }
    if (pending_version) {
        if (!send(proto_version(wire, seq, clock_us(), POLL_US, F_CPU)))
            return;
        pending_version = 0;
    }
    if (pending_nak_cmd) {
        if (!send(proto_nak(wire, seq, clock_us(), pending_nak_cmd, pending_nak_err)))
            return;
        pending_nak_cmd = 0;
    }
}

static void apply_cpi(void)
{
    config_bits = adns_set_cpi(cpi);
    cpi_pending = 0;
    pending_status = REASON_ACK;
}

/* ---------------------------------------------------------------- sensor states */

static void start_reset(uint32_t now)
{
    adns_reset_pulse();
    reset_at = now;
    deadline = now + T_IN_RST_US;
    state = S_RESET_WAIT;
}

static void sensor_missing(uint32_t now, uint8_t reason)
{
    retries++;
    state = S_RETRY;
    deadline = now + RETRY_US;
    pending_status = reason;
}

static void check_sensor(uint32_t now)
{
    if (!adns_check_id(&product_id)) {
        sensor_missing(now, ever_ok ? REASON_FAULT : REASON_BOOT);
        return;
    }
    config_bits = adns_set_cpi(cpi);
    cpi_pending = 0;
    deadline = reset_at + T_PU_RESET_US;
    state = S_STARTUP;
}

static void start_run(void)
{
    pending_status = ever_ok ? REASON_RECOVERED : REASON_BOOT;
    ever_ok = 1;
    accum_clear(&acc);
    last_read_us = clock_us();
    state = S_RUN;
}

/* One poll covering `periods` poll periods, drained while the deltas come back at full
 * scale.  The sensor keeps summing between reads, so a late poll loses nothing; counting
 * the periods keeps `frames` a measure of time for Kim & Lee's eq. (50). */
static void poll_sensor(uint8_t periods)
{
    adns_burst_t b;
    for (uint8_t i = 0; i < DRAIN_MAX_READS; i++) {
        last_read_us = clock_us(); /* the burst freezes the deltas at this moment */
        adns_burst(&b);
        if (b.motion & ADNS_MOTION_RESERVED) {
            acc.flags |= FLAG_FAULT; /* MISO stuck high: nobody is answering */
            break;
        }
        accum_read(&acc, b.motion, b.dx, b.dy, b.squal);
        if (!(b.motion & ADNS_MOT) || !accum_saturated(b.dx, b.dy))
            break;
    }
    accum_frames(&acc, periods);
}

static void maybe_send_motion(uint32_t now)
{
    if (acc.frames < k)
        return;
    /* Verify the sensor once a packet (datasheet "Error detection and recovery" 5): a
     * sensor that vanished with MISO low would otherwise look like one that stands still. */
    uint8_t id;
    if (!adns_check_id(&id))
        acc.flags |= FLAG_FAULT;
    if (acc.frames > k)
        acc.flags |= FLAG_DELAYED;
    motion_pkt_t m = {
        .seq = seq,
        .t_us = last_read_us,
        .dx = acc.sx,
        .dy = acc.sy,
        .frames = acc.frames,
        .squal_min = acc.squal_min,
        .flags = (uint8_t)(acc.flags | boot_flag),
    };
    if (!send(proto_motion(wire, &m)))
        return; /* UART busy: keep summing, nothing is lost */
    boot_flag = 0;
    if (m.flags & FLAG_OVERFLOW)
        overflows++;
    uint8_t fault = m.flags & FLAG_FAULT;
    accum_clear(&acc);
    if (fault) {
        product_id = id;
        sensor_missing(now, REASON_FAULT);
        return;
    }
    if (cpi_pending)
        apply_cpi();
}

static void on_tick(uint8_t periods)
{
    uint32_t now = clock_us();
    switch (state) {
    case S_POWER:
        if (reached(now, T_OP_US))
            start_reset(now);
        break;
    case S_RESET_WAIT:
        if (reached(now, deadline))
            check_sensor(now);
        break;
    case S_STARTUP:
        if (reached(now, deadline))
            start_run();
        break;
    case S_RUN:
        poll_sensor(periods);
        maybe_send_motion(now);
        break;
    case S_RETRY:
        if (reached(now, deadline))
            start_reset(now);
        break;
    }
}

/* ---------------------------------------------------------------- host commands */

static void on_command(const uint8_t *body, uint8_t len)
{
    command_t c;
    uint8_t err = proto_parse_command(body, len, &c);
    if (err == NAK_CRC) {
        rx_errors++; /* the command byte itself cannot be trusted: no answer */
        return;
    }
    if (err) {
        pending_nak_cmd = c.cmd ? c.cmd : 0xFF;
        pending_nak_err = err;
        return;
    }
    switch (c.cmd) {
    case CMD_SET_K:
        k = c.k;
        pending_status = REASON_ACK;
        break;
    case CMD_SET_CPI:
        cpi = c.cpi;
        if (state == S_RUN)
            cpi_pending = 1; /* at the packet boundary: one packet, one resolution */
        else
            pending_status = REASON_ACK; /* applied by the next power-up */
        break;
    case CMD_GET_STATUS:
        pending_status = REASON_REQUEST;
        break;
    case CMD_GET_VERSION:
        pending_version = 1;
        break;
    }
}

static void serve_host(void)
{
    uint8_t b;
    while (uart_getc(&b)) {
        uint8_t r = cobs_dec_feed(&rx, b);
        if (r == COBS_FRAME)
            on_command(rx.buf, rx.len);
        else if (r == COBS_ERROR)
            rx_errors++;
    }
}

int main(void)
{
    adns_spi_init();
    uart_init();
    /* A lone 0x00 first: it ends whatever partial frame the host's receiver holds from
     * before this reset, so that the first packet of the boot arrives whole (without it,
     * STATUS seq 0 would be read as the tail of that frame and refused with it). */
    const uint8_t delimiter = 0;
    uart_write(&delimiter, 1);
    timer_init();
    cobs_dec_init(&rx);
    accum_clear(&acc);
    set_sleep_mode(SLEEP_MODE_IDLE);
    sei();
    for (;;) {
        cli();
        uint8_t periods = tick_pending;
        tick_pending = 0;
        sei();
        if (periods)
            on_tick(periods);
        serve_host();
        flush_replies();
        cli();
        if (!tick_pending && !uart_rx_ready()) {
            sleep_enable();
            sei(); /* SLEEP runs before any interrupt: no lost wake-up */
            sleep_cpu();
            sleep_disable();
        }
        sei();
    }
}
