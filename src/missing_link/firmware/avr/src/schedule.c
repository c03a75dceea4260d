/* When a periodic driver measures (Python: board/drivers/__init__.py, Periodic). */
#include "schedule.h"

#include "timing.h"

/* Aligned (timing.c): the next measurement is the grid's next instant in board ticks, and the
 * last stretch before it is waited out here (SCHED_SPIN_US), so the measurement starts within a
 * few µs of it; without a valid map it runs free and each such measurement is counted
 * (timing_unaligned), as the Python drivers do. */

static uint8_t sched_grid(schedule_t *s, uint32_t now) {
    s->free = 1;
    if (!s->aligned || !timing_next_grid(s->period_us, s->phase, now, &s->due)) return 0;
    s->free = 0;
    return 1;
}

/* 1 when it is time to measure: due, or aligned and due within SCHED_SPIN_US (then the driver
 * readies its measurement and calls sched_wait just before it starts).  The next instant is
 * reckoned on the call after a measurement, not before it: a grid instant costs a few 64-bit
 * divisions (about 1 ms on an AVR), which must not sit between the instant and the measurement. */
uint8_t sched_due(schedule_t *s, uint32_t *now) {
    if (!s->started) {
        s->started = 1;
        s->stale = 0;
        if (sched_grid(s, *now)) return 0; /* wait for the grid */
        s->due = *now;
    }
    if (s->stale) {
        s->stale = 0;
        if (!sched_grid(s, *now)) {
            s->due += s->period_us;
            if (clock_due(*now, s->due)) s->due = *now + s->period_us;
        }
        *now = clock_now();
    }
    if (!clock_due(*now, s->due) && !(s->aligned && !s->free && s->due - *now < SCHED_SPIN_US))
        return 0;
#if ML_TIMING
    if (s->aligned && s->free) timing_unaligned++;
#endif
    s->stale = 1;
    return 1;
}

void sched_rate(schedule_t *s, float rate_hz) {
    uint32_t p = (uint32_t)(1000000.0f / rate_hz);
    uint32_t last = s->stale ? s->due : s->due - s->period_us;
    if (s->aligned) s->started = 0; /* the grid of the new period */
    else if (s->started && p < s->period_us) { /* sooner */
        s->due = last + p;
        s->stale = 0;
    }
    s->period_us = p;
}

void sched_align(schedule_t *s, uint8_t aligned, float phase) {
    s->aligned = aligned;
    s->phase = phase;
    s->started = 0;
}

