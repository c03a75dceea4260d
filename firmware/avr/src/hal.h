/* The AVR below the runtime: the board clock (Timer1) and the UART link. */
#ifndef J2A_HAL_H
#define J2A_HAL_H
#include <stdint.h>

#define CLOCK_PERIOD_US 20000UL /* Timer1 wraps every 20 ms: also the servo's 50 Hz frame */

void board_clock_init(void);
uint64_t board_clock(void);           /* µs since boot, 64 bit, never wraps */
uint64_t board_clock_from_isr(void);  /* the same, with interrupts already off */

void link_init(uint32_t baud);
uint8_t link_read(uint8_t *b, uint64_t *rx_us); /* 1 if a byte was there */
void link_write(uint8_t b);                     /* waits while the TX ring is full */
uint16_t link_tx_free(void);
uint16_t link_rx_dropped(void);
#endif
