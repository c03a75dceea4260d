/* The AVR below the runtime: the board clock (Timer1) and the UART link. */
#ifndef J2A_HAL_H
#define J2A_HAL_H
#include <avr/io.h>
#include <stdint.h>

#define CLOCK_PERIOD_US 20000UL /* Timer1 wraps every 20 ms: also the servo's 50 Hz frame */

/* Time on the board.  The clock is 64-bit µs since boot where it leaves the board (a SIF's
 * stamps, a2jClock, the log, the host map), but what the firmware keeps and schedules runs on
 * its low 32 bits (`now`: board µs mod 2^32, wrapping every 71.6 min), compared by signed
 * difference (clock_due): 8-bit code carries half the bytes, and a stamp goes out widened to
 * 64 bits (clock_widen), exact for any time within 35 min of now, which every time kept is
 * (stamps a period old, deadlines seconds ahead). */
void board_clock_init(void);
uint64_t board_clock(void);          /* µs since boot, 64 bit, never wraps */
uint32_t clock_now(void);            /* its low 32 bits */
uint32_t clock_now_from_isr(void);   /* the same, with interrupts already off */
uint32_t clock_ticks_from_isr(void); /* Timer1's ticks (0.5 µs) since it started, mod 2^32, irqs off */
/* the 64-bit board µs of `us` (low 32 bits, within 35 min of now) */
uint64_t clock_widen(uint32_t us);
/* 1 when `at` has come by `now` (both low 32 bits, within 35 min of each other) */
static inline uint8_t clock_due(uint32_t now, uint32_t at) { return (int32_t)(now - at) >= 0; }
/* Timer1's wraps when it read ``ticks`` just now, counting one still pending (irqs off) */
uint32_t clock_wraps_at(uint16_t ticks);
/* the clock (low 32 bits) at a count read earlier: Timer1's wraps (within 256 of now), ticks */
uint32_t clock_at(uint32_t wraps, uint16_t ticks);
/* Waiting for board µs `at_us` to within a timer tick (0.5 µs) on Timer1 itself, for waits under
 * 20 ms: prepare (0: the time has come already), then clock_wait, inline, right before what
 * must happen then. */
typedef struct {
    uint16_t from, ticks; /* TCNT1 then, and the ticks to wait from it */
} clock_wait_t;
uint8_t clock_wait_prepare(uint32_t at_us, clock_wait_t *w);
static inline __attribute__((always_inline)) void clock_wait(const clock_wait_t *w) {
    for (;;) {
        uint16_t c = TCNT1;
        uint16_t gone = c >= w->from ? c - w->from : (uint16_t)(c + 40000u - w->from);
        if (gone >= w->ticks) return;
    }
}

void link_init(uint32_t baud);
uint8_t link_read(uint8_t *b, uint32_t *rx_us); /* 1 if a byte was there (and its stamp) */
void link_write(uint8_t b);                     /* waits while the TX ring is full */
uint16_t link_tx_free(void);
uint16_t link_rx_dropped(void);
#endif
