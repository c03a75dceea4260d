/* Acting on host time on AVR: the same functions and texts as board/timing.py (Python). */
#ifndef J2A_TIMING_H
#define J2A_TIMING_H
#include <stdint.h>

#include "features.h"

#define MAP_LIFE_US 10000000LL
#define TIMED_QUEUE 4
#define TIMED_PAYLOAD 4

#if ML_TIMING
/* The board tick (board µs, low 32 bits: hal.h) of the first grid instant after now (1), or 0
 * without a valid map. */
uint8_t timing_next_grid(uint32_t period_us, float phase, uint32_t now, uint32_t *tick);
void timing_poll(uint32_t now); /* timed calls that are due (the main loop) */
uint8_t timing_pending(void);   /* timed calls not yet carried out (queued or handed on) */
/* Drops the timed calls not yet carried out (`all`, or those due after board µs `after`: the
 * host is gone since, failsafe.c), counted (timing_cancelled) and said in a2jDebug: `why` (in
 * flash), then " for `ms` ms" unless ms is 0xFFFFFFFF. */
void timing_cancel(const char *why, uint32_t ms, uint8_t all, uint32_t after);

uint8_t host_map_fn(const uint8_t *in, uint8_t n, uint8_t *out, uint8_t *out_n);
uint8_t timing_at(const uint8_t *in, uint8_t n, uint8_t *out, uint8_t *out_n);   /* a2jAt */
uint8_t timing_info(const uint8_t *in, uint8_t n, uint8_t *out, uint8_t *out_n); /* a2jAlignInfo */
extern uint32_t timing_unaligned, timing_done, timing_refused, timing_cancelled;

/* A function a timed call may be handed to at its tick, by the hardware (board_gen.c: the
 * trigger's; 0: none): returns 1 if it took the call. */
extern uint8_t (*timing_hardware)(uint8_t fn, uint32_t tick, const uint8_t *payload, uint8_t n);
/* ... and how many calls (all, or due after board µs `after`) that hardware took and has not
 * yet carried out, dropping them when `drop` (trigger.c sets it; 0: none). */
extern uint8_t (*timing_hardware_held)(uint8_t drop, uint8_t all, uint32_t after);
#else /* no host time: drivers run free, no timed call is ever queued */
static inline uint8_t timing_next_grid(uint32_t p, float ph, uint32_t now, uint32_t *tick) {
    (void)p, (void)ph, (void)now, (void)tick;
    return 0;
}
static inline void timing_poll(uint32_t now) { (void)now; }
static inline uint8_t timing_pending(void) { return 0; }
static inline void timing_cancel(const char *why, uint32_t ms, uint8_t all, uint32_t after) {
    (void)why, (void)ms, (void)all, (void)after;
}
#endif
#endif
