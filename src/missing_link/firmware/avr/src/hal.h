/* The AVR below the runtime: the board clock (Timer1) and the UART link. */
#ifndef J2A_HAL_H
#define J2A_HAL_H
#include <avr/io.h>
#include <stdint.h>

#define CLOCK_PERIOD_US 20000UL /* Timer1 wraps every 20 ms: also the servo's 50 Hz frame */

void board_clock_init(void);
uint64_t board_clock(void);           /* µs since boot, 64 bit, never wraps */
uint64_t board_clock_from_isr(void);  /* the same, with interrupts already off */
uint64_t clock_ticks_from_isr(void);  /* Timer1's ticks (0.5 µs) since it started, irqs off */
/* Timer1's wraps when it read ``ticks`` just now, counting one still pending (irqs off) */
uint32_t clock_wraps_at(uint16_t ticks);
/* the clock at a count read earlier: Timer1's wraps (within 256 of now) and ticks */
uint64_t clock_at(uint32_t wraps, uint16_t ticks);
/* Waiting for board µs `at_us` to within a timer tick (0.5 µs) on Timer1 itself (a
 * board_clock() costs ~19 µs of 64-bit arithmetic), for waits under 20 ms: prepare (0: the time
 * has come already), then clock_wait, inline, right before what must happen then. */
typedef struct {
    uint16_t from, ticks; /* TCNT1 then, and the ticks to wait from it */
} clock_wait_t;
uint8_t clock_wait_prepare(uint64_t at_us, clock_wait_t *w);
static inline __attribute__((always_inline)) void clock_wait(const clock_wait_t *w) {
    for (;;) {
        uint16_t c = TCNT1;
        uint16_t gone = c >= w->from ? c - w->from : (uint16_t)(c + 40000u - w->from);
        if (gone >= w->ticks) return;
    }
}

void link_init(uint32_t baud);
uint8_t link_read(uint8_t *b, uint64_t *rx_us); /* 1 if a byte was there */
void link_write(uint8_t b);                     /* waits while the TX ring is full */
uint16_t link_tx_free(void);
uint16_t link_rx_dropped(void);
#endif
