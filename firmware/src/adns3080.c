#include "adns3080.h"

#include <avr/io.h>
#include <util/delay.h>

#include "board.h"

void adns_spi_init(void)
{
    /* NCS high before it becomes an output, so the sensor never sees a false select */
    PORTB |= (1 << PIN_NCS) | (1 << PIN_NPD);
    PORTB &= (uint8_t) ~(1 << PIN_RESET);
    DDRB |= (1 << PIN_NCS) | (1 << PIN_MOSI) | (1 << PIN_SCK) | (1 << PIN_RESET) | (1 << PIN_NPD);
    /* master, mode 3 (CPOL=1, CPHA=1), F_CPU/4 */
    SPCR = (1 << SPE) | (1 << MSTR) | (1 << CPOL) | (1 << CPHA);
}

static uint8_t xfer(uint8_t b)
{
    SPDR = b;
    while (!(SPSR & (1 << SPIF))) {
    }
    return SPDR;
}

static void select(void) { PORTB &= (uint8_t) ~(1 << PIN_NCS); }
static void deselect(void) { PORTB |= (1 << PIN_NCS); }

void adns_reset_pulse(void)
{
    PORTB |= (1 << PIN_RESET);
    _delay_us(T_PW_RESET_US);
    PORTB &= (uint8_t) ~(1 << PIN_RESET);
}

uint8_t adns_read(uint8_t reg)
{
    select();
    xfer(reg & 0x7F);
    if (reg == REG_MOTION)
        _delay_us(T_SRAD_MOT_US);
    else
        _delay_us(T_SRAD_US);
    uint8_t v = xfer(0);
    deselect();
    _delay_us(T_SRR_US);
    return v;
}

void adns_write(uint8_t reg, uint8_t value)
{
    select();
    xfer(reg | 0x80);
    xfer(value);
    deselect();
    _delay_us(T_SWW_US);
}

void adns_burst(adns_burst_t *b)
{
    select();
    xfer(REG_MOTION_BURST);
    _delay_us(T_SRAD_MOT_US);
    b->motion = xfer(0);
    b->dx = (int8_t)xfer(0);
    b->dy = (int8_t)xfer(0);
    b->squal = xfer(0);
    deselect();
    _delay_us(T_BEXIT_US);
}

uint8_t adns_check_id(uint8_t *product_id)
{
    uint8_t id = adns_read(REG_PRODUCT_ID);
    uint8_t inv = adns_read(REG_INVERSE_PRODUCT_ID);
    *product_id = id;
    return id == ADNS_PRODUCT_ID && inv == ADNS_INVERSE_PRODUCT_ID;
}

uint8_t adns_set_cpi(uint16_t cpi)
{
    uint8_t c = adns_read(REG_CONFIGURATION_BITS);
    if (cpi == 1600)
        c |= CONFIG_RES_1600;
    else
        c &= (uint8_t)~CONFIG_RES_1600;
    c &= 0x7F; /* bit 7 must always be written as zero */
    adns_write(REG_CONFIGURATION_BITS, c);
    return adns_read(REG_CONFIGURATION_BITS);
}
