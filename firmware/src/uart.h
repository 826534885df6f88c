/* Interrupt-driven UART with fixed ring buffers (no dynamic memory). */
#ifndef UART_H
#define UART_H
#include <stdint.h>

#define UART_TX_SIZE 128 /* powers of two */
#define UART_RX_SIZE 32

void uart_init(void);
uint8_t uart_tx_free(void);
/* Queue n bytes; the caller has checked uart_tx_free() >= n. */
void uart_write(const uint8_t *data, uint8_t n);
/* Next received byte into *b; 0 when none.  *overrun counts bytes lost to a full ring. */
uint8_t uart_getc(uint8_t *b);
uint16_t uart_rx_overruns(void);
uint8_t uart_rx_ready(void);

#endif
