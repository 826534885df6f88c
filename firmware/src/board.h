/* Board wiring and clocks of the downsampler (ATmega8L at 3.3 V, like the ADNS-3080).
 *
 *   PB0 -> ADNS NPD (held high: never power down)     PB3 -> MOSI
 *   PB1 -> ADNS RESET (active high)                   PB4 <- MISO
 *   PB2 -> ADNS NCS (the SPI SS pin, active low)      PB5 -> SCLK
 *   PD0/PD1 UART to the host (RXD/TXD)
 *
 * 7.3728 MHz crystal: 115200 baud is exact (UBRR = 3), SPI at F_CPU/4 = 1.84 MHz stays
 * under the sensor's 2 MHz, Timer1 at F_CPU/8 ticks at 921600 Hz (see usclock.h). */
#ifndef BOARD_H
#define BOARD_H

#ifndef F_CPU
#define F_CPU 7372800UL
#endif
#ifndef BAUD
#define BAUD 115200UL
#endif
#define UBRR_VALUE ((F_CPU + 8UL * BAUD) / (16UL * BAUD) - 1UL)

/* Poll period: 1152 ticks of 625/576 us = 1250 us exactly (800 polls/s).  At 1600 CPI
 * and the sensor's 40 ips limit that is 80 counts a poll: under the 8-bit full scale, so
 * the drain loop only runs when the sensor is pushed past its specification. */
#define POLL_TICKS 1152u
#define POLL_US 1250u

#define PIN_NPD PB0
#define PIN_RESET PB1
#define PIN_NCS PB2
#define PIN_MOSI PB3
#define PIN_MISO PB4
#define PIN_SCK PB5

#define DEFAULT_K 12
#define DEFAULT_CPI 1600

/* ADNS-3080 datasheet timings (AC Electrical Specifications, p. 10) in microseconds */
#define T_OP_US 250000UL      /* VDD to RESET sampled (max) */
#define T_PW_RESET_US 12      /* RESET pulse width, >= 10 us */
#define T_IN_RST_US 600UL     /* inputs active after RESET falls: 500 us, plus margin */
#define T_PU_RESET_US 35000UL /* RESET falling to valid motion data */
#define T_SRAD_US 50          /* address to data, ordinary registers */
#define T_SRAD_MOT_US 75      /* address to data, Motion and Motion_Burst */
#define T_SWW_US 50           /* after a write, before the next write or read */
#define T_BEXIT_US 4          /* NCS high to leave burst mode */
#define T_SRR_US 1            /* between reads (250 ns) */
#define RETRY_US 1000000UL    /* a missing sensor is tried again every second */

#endif
