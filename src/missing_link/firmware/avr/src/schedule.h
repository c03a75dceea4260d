/* When a periodic driver measures (schedule.c): every period, or on the host-time grid. */
#ifndef J2A_SCHEDULE_H
#define J2A_SCHEDULE_H
#include <stdint.h>

#include "hal.h"

#ifndef SCHED_SPIN_US
#define SCHED_SPIN_US 400
#endif

typedef struct {
    uint32_t due; /* the next measurement (stale: the last one's), board µs (hal.h) */
    uint32_t period_us;
    float phase;
    uint8_t aligned : 1, started : 1, free : 1, stale : 1;
} schedule_t;

uint8_t sched_due(schedule_t *s, uint32_t *now);
void sched_rate(schedule_t *s, float rate_hz);
void sched_align(schedule_t *s, uint8_t aligned, float phase);

/* the last stretch to an aligned measurement's instant (*now: that instant, within a tick) */
static inline __attribute__((always_inline)) void sched_wait(schedule_t *s, uint32_t *now) {
    clock_wait_t w;
    if (clock_due(*now, s->due) || !clock_wait_prepare(s->due, &w)) return;
    *now = s->due;
    clock_wait(&w);
}

#endif
