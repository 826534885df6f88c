#include "uart.h"

#include <avr/interrupt.h>
#include <avr/io.h>

#include "board.h"

static uint8_t tx_buf[UART_TX_SIZE];
static volatile uint8_t tx_head, tx_tail;
static uint8_t rx_buf[UART_RX_SIZE];
static volatile uint8_t rx_head, rx_tail;
static volatile uint16_t rx_overruns;

void uart_init(void)
{
    /* simavr 1.6 does not model URSEL sharing UBRRH and UCSRC: this order (UCSRC, then
     * UBRRH, UBRRL last) is right on the chip and in the simulator. */
    UCSRA = 0;
    UCSRB = (1 << RXEN) | (1 << TXEN) | (1 << RXCIE);
    UCSRC = (1 << URSEL) | (1 << UCSZ1) | (1 << UCSZ0); /* 8N1 */
    UBRRH = (uint8_t)(UBRR_VALUE >> 8);
    UBRRL = (uint8_t)UBRR_VALUE;
}

uint8_t uart_tx_free(void)
{
    return (uint8_t)(UART_TX_SIZE - 1 - ((uint8_t)(tx_head - tx_tail) & (UART_TX_SIZE - 1)));
}

void uart_write(const uint8_t *data, uint8_t n)
{
    while (n--) {
        tx_buf[tx_head & (UART_TX_SIZE - 1)] = *data++;
        tx_head++;
    }
    UCSRB |= (1 << UDRIE);
}

ISR(USART_UDRE_vect)
{
    if (tx_head == tx_tail) {
        UCSRB &= (uint8_t) ~(1 << UDRIE);
        return;
    }
    UDR = tx_buf[tx_tail & (UART_TX_SIZE - 1)];
    tx_tail++;
}

ISR(USART_RXC_vect)
{
    uint8_t b = UDR;
    if ((uint8_t)(rx_head - rx_tail) >= UART_RX_SIZE) {
        rx_overruns++;
        return;
    }
    rx_buf[rx_head & (UART_RX_SIZE - 1)] = b;
    rx_head++;
}

uint8_t uart_getc(uint8_t *b)
{
    if (rx_head == rx_tail)
        return 0;
    *b = rx_buf[rx_tail & (UART_RX_SIZE - 1)];
    rx_tail++;
    return 1;
}

uint16_t uart_rx_overruns(void)
{
    uint8_t s = SREG;
    cli();
    uint16_t v = rx_overruns;
    SREG = s;
    return v;
}

uint8_t uart_rx_ready(void) { return rx_head != rx_tail; }
