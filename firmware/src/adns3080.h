/* ADNS-3080 register access over the ATmega8's SPI (mode 3, MSB first). */
#ifndef ADNS3080_H
#define ADNS3080_H
#include <stdint.h>

#define REG_PRODUCT_ID 0x00
#define REG_MOTION 0x02
#define REG_SQUAL 0x05
#define REG_CONFIGURATION_BITS 0x0A
#define REG_MOTION_CLEAR 0x12
#define REG_INVERSE_PRODUCT_ID 0x3F
#define REG_MOTION_BURST 0x50

#define ADNS_PRODUCT_ID 0x17
#define ADNS_INVERSE_PRODUCT_ID 0xF8
#define CONFIG_RES_1600 0x10 /* Configuration_bits bit 4 */

typedef struct {
    uint8_t motion;
    int8_t dx, dy;
    uint8_t squal;
} adns_burst_t;

void adns_spi_init(void);
void adns_reset_pulse(void);
uint8_t adns_read(uint8_t reg);
void adns_write(uint8_t reg, uint8_t value);
/* Motion burst: Motion, Delta_X, Delta_Y, SQUAL, then NCS up (the remaining burst
 * registers, shutter and maximum pixel, are not needed). */
void adns_burst(adns_burst_t *b);
/* Product_ID and Inverse_Product_ID both right? Stores what Product_ID said. */
uint8_t adns_check_id(uint8_t *product_id);
/* Read-modify-write Configuration_bits bit 4; returns the value read back. */
uint8_t adns_set_cpi(uint16_t cpi);

#endif
