/* The failsafe: see board/failsafe.py (Python) for the theory of operation; the same keys
 * (`failsafe_ms` per actuator), functions (a2jGoodbye, a2jFailsafe), debug texts and a log line
 * (WARN) per trip.  An
 * actuator is armed by a command it takes and trips once when the host has been silent for its
 * failsafe_ms (runtime.c notes every intact request for a function of the table:
 * damaged frames, and error frames heard back, are not the host).  Timed calls not yet carried
 * out (timing.c) are dropped on a2jGoodbye, and those due after the moment the host had been
 * silent for the shortest failsafe_ms: a timed call names a function, not an actuator, so the
 * shortest guards them all. */
#include "failsafe.h"

#include <avr/pgmspace.h>
#include <string.h>

#include "hal.h"
#include "log.h"
#include "runtime.h"
#include "timing.h"

#define NO_SILENCE 0xFFFFFFFFUL
static const char silent[] PROGMEM = "no frame from the host";
static const char goodbye[] PROGMEM = "the host said goodbye";

static const failsafe_entry_t *table;
static uint16_t *ms;
static uint8_t count, armed; /* armed: a bit per actuator commanded since it was made safe */
static uint64_t last_trip;
static uint32_t trips;

void failsafe_init(const failsafe_entry_t *t, uint16_t *m, uint8_t n) {
    table = t;
    ms = m;
    count = n > 8 ? 8 : n;
}

static void trip(uint8_t i, const char *why, uint32_t silent_ms) {
    failsafe_entry_t e;
    memcpy_P(&e, &table[i], sizeof e);
    armed &= (uint8_t)~(1 << i);
    trips++;
    last_trip = board_clock();
    e.make_safe();
    log_line_P(LOG_WARN, board_transducers[e.k].tid, PSTR("made safe: "), why);
    runtime_debug_P(PSTR("failsafe: "));
    runtime_debug_P(e.name);
    runtime_debug_P(PSTR(" safe ("));
    runtime_debug_why(why, silent_ms);
}

void failsafe_arm(uint8_t k) {
    for (uint8_t i = 0; i < count; i++)
        if (pgm_read_byte(&table[i].k) == k) armed |= (uint8_t)(1 << i);
}

void failsafe_poll(uint32_t now) {
    uint32_t quiet = now - runtime_last_frame_us; /* (hal.h: within 71 min, a trip's long past) */
    uint16_t least = 0; /* the shortest non-zero failsafe_ms */
    for (uint8_t i = 0; i < count; i++) {
        if (ms[i] && (!least || ms[i] < least)) least = ms[i];
        if (ms[i] && (armed & (1 << i)) && quiet >= (uint32_t)ms[i] * 1000)
            trip(i, silent, quiet / 1000);
    }
    if (least && quiet >= (uint32_t)least * 1000 && timing_pending()) /* those due after then */
        timing_cancel(silent, quiet / 1000, 0,
                      runtime_last_frame_us + (uint32_t)least * 1000);
}

uint8_t failsafe_goodbye(const uint8_t *in, uint8_t n, uint8_t *out, uint8_t *out_n) {
    (void)in;
    (void)n;
    (void)out;
    *out_n = 0;
    timing_cancel(goodbye, NO_SILENCE, 1, 0); /* (first: none runs meanwhile) */
    for (uint8_t i = 0; i < count; i++)
        if (armed & (1 << i)) trip(i, goodbye, NO_SILENCE);
    return 0;
}

uint8_t failsafe_info(const uint8_t *in, uint8_t n, uint8_t *out, uint8_t *out_n) {
    (void)in;
    (void)n;
    uint32_t age = 0xFFFFFFFFUL;
    if (trips) {
        uint64_t d = (board_clock() - last_trip) / 1000;
        age = d > 0xFFFFFFFEULL ? 0xFFFFFFFEUL : (uint32_t)d;
    }
    memcpy(out, &trips, 4);
    memcpy(out + 4, &age, 4);
    *out_n = 8;
    return 0;
}
