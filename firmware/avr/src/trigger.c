/* The trigger output (drivers.h): a pulse on Timer2's output-compare pin, now or at a board tick.
 *
 * Theory of operation
 * -------------------
 * The pulse's edges are made by the timer's hardware, not by code: OC2A (Uno D11, Mega D10) is
 * set or cleared by the compare match itself (COM2A), so an edge lands on its timer tick (0.5 µs)
 * whatever the CPU is doing then.  Timer2 counts the board clock's ticks mod 256 (hal.c starts
 * it with Timer1, at 2 MHz), so it wraps every 128 µs and tick T's match is OCR2A = T - 1.
 *
 * A match for OCR2A = y happens as TCNT2 goes from y to y + 1.  An edge R ticks ahead is reached
 * in steps from match to match: whole wraps (OCR2A unchanged) or a half one while more than a
 * wrap is left, then the rest; only the last step's compare mode makes the edge, the steps
 * before it use the opposite mode (clearing a low pin, setting a high one: nothing moves).  Every
 * step is at least MIN_STEP ticks, so the interrupt that sets up the next one has that long.
 *
 * A timed pulse (trigger_at, from a2jAt) is armed from the main loop once its tick is less than
 * ARM_US away; its rising edge is at the tick, its falling edge `width` µs later.  One pulse is
 * under way at a time: a timed call for another while one is armed goes to timing.c's queue and
 * is made "now" when due.  A pulse commanded now starts MIN_STEP ticks after the command.  The
 * sample is the width, stamped with the tick of the rising edge.  When the rising edge's
 * interrupt runs so late that the falling edge's match may have passed already (a pulse not
 * much longer than MIN_STEP ticks, or interrupts held off), the pulse ends by forcing the
 * compare (FOC2A) then: on time or late by as much as the interrupt was, never shorter than
 * asked, and counted (trigger_late).
 */
#include <avr/interrupt.h>
#include <avr/io.h>
#include <avr/pgmspace.h>
#include <string.h>

#include "drivers.h"
#include "hal.h"
#include "timing.h"

#if defined(__AVR_ATmega328P__)
#define TRIG_BIT PB3 /* OC2A: Uno D11 */
#else
#define TRIG_BIT PB4 /* OC2A: Mega D10 */
#endif
#define COM_MASK (_BV(COM2A1) | _BV(COM2A0))
#define COM_SET (_BV(COM2A1) | _BV(COM2A0))
#define COM_CLEAR _BV(COM2A1)
#define MIN_STEP 32    /* timer ticks (16 µs) */
#define ARM_US 20000UL /* a timed pulse is armed this long before its tick */
#define TIMER_WRAP 40000UL /* Timer1's ticks per wrap (hal.c: 20 ms at 2 MHz) */

enum { IDLE, RISING, FALLING };
static transducer_t *trig_t;
static uint16_t trig_pulse_us, trig_width;
static uint64_t trig_tick;          /* board µs of the rising edge (pending or under way) */
static uint8_t trig_pending;        /* a timed pulse waits to be armed */
static uint8_t trig_timed;          /* the pulse under way is a timed call (timing_done) */
static volatile uint8_t trig_state; /* IDLE, RISING (armed), FALLING */
static volatile uint32_t trig_rest; /* ticks to go after the step set up now */
static volatile uint8_t trig_fired; /* the rising edge was made: record it (main loop) */
uint16_t trigger_pulses;
volatile uint16_t trigger_late; /* pulses whose falling edge was forced (above) */

/* the next step: r ticks after the match of OCR2A = from (or the instant TCNT2 became from + 1);
 * returns the step's length */
static uint16_t step(uint8_t from, uint32_t r, uint8_t mode) {
    uint16_t s = r <= 255 ? (uint16_t)r : r >= 256 + MIN_STEP ? 256 : 128;
    trig_rest = r - s;
    uint8_t m = trig_rest ? (mode == COM_SET ? COM_CLEAR : COM_SET) : mode;
    TCCR2A = (uint8_t)((TCCR2A & (uint8_t)~COM_MASK) | m);
    OCR2A = (uint8_t)(from + s);
    return s;
}

static void finish(void) {
    TIMSK2 &= (uint8_t)~_BV(OCIE2A);
    TCCR2A &= (uint8_t)~COM_MASK; /* the pin is PORTB's again: low */
    trig_state = IDLE;
}

ISR(TIMER2_COMPA_vect) {
    uint8_t from = OCR2A; /* the match just made */
    if (trig_rest) {
        step(from, trig_rest, trig_state == RISING ? COM_SET : COM_CLEAR);
        return;
    }
    if (trig_state != RISING) { /* the falling edge was just made */
        finish();
        return;
    }
    trig_fired = 1;
    trig_state = FALLING;
    uint16_t s = step(from, (uint32_t)trig_width * 2, COM_CLEAR);
    if (!trig_rest && (uint16_t)((uint8_t)(TCNT2 - from) + 2) >= s) { /* its match may be gone already */
        TCCR2B |= _BV(FOC2A);
        trigger_late++;
        finish();
    }
}

void trigger_init(transducer_t *t, uint16_t pulse_us) {
    trig_t = t;
    trig_pulse_us = pulse_us;
    PORTB &= (uint8_t)~_BV(TRIG_BIT);
    DDRB |= _BV(TRIG_BIT);
}

void trigger_set(uint16_t pulse_us) { trig_pulse_us = pulse_us; }

/* Arms the rising edge at board µs `tick`: 0 when that is less than MIN_STEP ticks away. */
static uint8_t arm(uint64_t tick) {
    cli();
    uint16_t c1 = TCNT1;
    uint64_t now = (uint64_t)clock_wraps_at(c1) * TIMER_WRAP + c1; /* ticks; TCNT2 = now mod 256 */
    int64_t r = (int64_t)(tick * 2) - (int64_t)now;
    if (r < MIN_STEP) {
        sei();
        return 0;
    }
    trig_state = RISING;
    step((uint8_t)(now - 1), (uint32_t)r, COM_SET);
    TIFR2 = _BV(OCF2A);
    TIMSK2 |= _BV(OCIE2A);
    sei();
    return 1;
}

static uint16_t width_of(const uint8_t *in, uint8_t n) {
    uint16_t w = n == 2 ? (uint16_t)(in[0] | (in[1] << 8)) : 0;
    return w ? w : trig_pulse_us;
}

uint8_t trigger_command(const uint8_t *in, uint8_t n, uint8_t *out, uint8_t *out_n) {
    /* now: the rising edge MIN_STEP ticks from here */
    *out_n = 0;
    if (n != 2) return 0xFF;
    if (trig_state != IDLE || trig_pending) {
        static const char why[] PROGMEM = "a pulse is under way";
        strcpy_P((char *)out, why);
        *out_n = sizeof why - 1;
        return 0xFF;
    }
    trig_width = width_of(in, n);
    trig_timed = 0;
    trig_tick = board_clock() + MIN_STEP; /* (µs: twice the least) */
    arm(trig_tick);
    return 0;
}

uint8_t trigger_at(const uint8_t *payload, uint8_t n, uint64_t tick) {
    if (trig_state != IDLE || trig_pending || n != 2) return 0; /* timing.c queues it */
    trig_width = width_of(payload, n);
    trig_tick = tick;
    trig_pending = 1;
    trig_timed = 1;
    return 1;
}

void trigger_poll(uint64_t now) {
    if (trig_fired) {
        trig_fired = 0;
        trigger_pulses++;
        if (trig_timed) timing_done++;
        record(trig_t, 0, trig_width, trig_tick);
    }
    if (!trig_pending || trig_tick > now + ARM_US) return;
    trig_pending = 0;
    if (!arm(trig_tick)) { /* the loop came too late: now, late by that much */
        trig_tick = board_clock() + MIN_STEP;
        arm(trig_tick);
    }
}
