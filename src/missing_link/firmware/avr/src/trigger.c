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
 * step but a final one is at least MIN_STEP ticks, longer than the interrupt that sets up the
 * next one is ever held off (hal.c keeps interrupts off only for snapshots of its counts).
 *
 * The race this closes: a compare written after the count has reached its value waits a whole
 * wrap for its match, so an interrupt that came late (held off by other code) put an edge
 * exactly 128 µs late without a word; and a write in the very tick of the match may or may not
 * make it (the datasheet's comparator sees the new OCR2A only from the next timer clock).  So
 * before each write the interrupt reads TCNT2 (aim): a step is written only if its match is at
 * least LEAD ticks away (the code from that read to the writes of OCR2A and TIFR2 takes under
 * 26 cycles, 3.25 ticks, and the count must not reach the new value before the write: a tick to
 * spare and more); else the step is taken from the count now; and an edge itself less than
 * LEAD ticks away, or past, is forced (FOC2A: the compare mode applied at once, no flag) at its
 * tick or at once, and counted (trigger_late).  So every edge lands on its tick or is counted,
 * late by about as much as its interrupt was, never a wrap.
 *
 * A timed pulse (trigger_at, from a2jAt) is armed from the main loop once its tick is less than
 * ARM_US away; its rising edge is at the tick, its falling edge `width` µs after the rising one.
 * One pulse is under way at a time: a timed call for another while one is armed goes to
 * timing.c's queue and is made "now" when due.  A pulse commanded now starts MIN_STEP ticks after
 * the command.  The sample is the width, stamped with the board µs of the rising edge (its
 * tick, or where it was forced).  A main loop that comes to arm a pulse too late starts it now,
 * counted too.
 */
#include <avr/interrupt.h>
#include <avr/io.h>
#include <avr/pgmspace.h>
#include <string.h>
#include <util/atomic.h>

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
#define MIN_STEP 64    /* timer ticks (32 µs): the shortest step but a final one */
#define LEAD 8         /* timer ticks: the least a compare is written ahead of its match */
#ifndef BOARD_BAUD
#define BOARD_BAUD 115200UL
#endif
/* a timed pulse is armed this long before its tick: 20 ms, and twice the time a full TX ring
 * (256 bytes, hal.c) takes to drain, for which a reply can hold the main loop up (64 ms at
 * 115200 baud); armed later, it starts late (counted) */
#define ARM_US (20000UL + 2 * (256UL * 10 * 1000000UL / BOARD_BAUD))

enum { IDLE, RISING, FALLING };
static transducer_t *trig_t;
static uint16_t trig_pulse_us, trig_width;
static uint32_t trig_tick;          /* board µs (hal.h) of the rising edge (pending or under way) */
static uint8_t trig_pending;        /* a timed pulse waits to be armed */
static uint8_t trig_timed;          /* the pulse under way is a timed call (timing_done) */
static volatile uint8_t trig_state; /* IDLE, RISING (armed), FALLING */
static volatile uint32_t trig_rest; /* ticks to go after the step set up now */
static volatile uint8_t trig_fired; /* the rising edge was made: record it (main loop) */
static volatile uint8_t trig_rose_late; /* ticks the rising edge was forced after its tick */
uint16_t trigger_pulses;
volatile uint16_t trigger_late; /* edges forced instead of made by a compare (above) */

static void finish(void) {
    TIMSK2 &= (uint8_t)~_BV(OCIE2A);
    TCCR2A &= (uint8_t)~COM_MASK; /* the pin is PORTB's again: low */
    trig_state = IDLE;
}

/* Interrupts off.  Sets the trigger on its way to its next edge, r ticks after the instant TCNT2
 * became from + 1 (the match of OCR2A = from): the next compare step (theory above), if its
 * match is at least LEAD ticks from now; else one from now; and when the edge itself is less
 * than LEAD ticks away, or gone (the interrupt came that late), no compare can make it: it is
 * forced (FOC2A) at its tick or at once, counted, and a forced rising edge goes on to its fall. */
static void aim(uint8_t from, uint32_t r) {
    for (;;) {
        uint8_t mode = trig_state == RISING ? COM_SET : COM_CLEAR;
        uint16_t s = r <= 255 ? (uint16_t)r : r >= 256 + MIN_STEP ? 256 : 128;
        uint8_t com = (uint8_t)(r == s ? mode : mode == COM_SET ? COM_CLEAR : COM_SET);
        com |= (uint8_t)(TCCR2A & (uint8_t)~COM_MASK);
        uint8_t c = TCNT2, gone = (uint8_t)(c - from - 1); /* ticks since that instant */
        if (s >= (uint16_t)(gone + LEAD)) {
            /* OCR2A first: with the mode first, the value before (armed from idle: any) could
             * match in between, and make the edge then */
            OCR2A = (uint8_t)(from + s);
            TCCR2A = com;
            TIFR2 = _BV(OCF2A); /* (a match of the value before) */
            trig_rest = r - s;
            return;
        }
        if (r >= (uint32_t)gone + LEAD) { /* the interrupt came late: a step from now */
            from = (uint8_t)(c - 1);
            r -= gone;
            continue;
        }
        uint8_t wait = r > gone ? (uint8_t)(r - gone) : 0; /* (< LEAD) */
        while ((uint8_t)(TCNT2 - c) < wait) {
        }
        TCCR2A = (uint8_t)((TCCR2A & (uint8_t)~COM_MASK) | mode);
        TCCR2B |= _BV(FOC2A);
        uint8_t at = TCNT2;
        trigger_late++;
        if (trig_state != RISING) {
            finish();
            return;
        }
        trig_rose_late = r < gone ? (uint8_t)(gone - r) : 0;
        trig_fired = 1;
        trig_state = FALLING;
        from = (uint8_t)(at - 1);
        r = (uint32_t)trig_width * 2;
    }
}

ISR(TIMER2_COMPA_vect) {
    uint8_t from = OCR2A; /* the match just made */
    uint32_t r = trig_rest;
    if (!r) { /* that match made an edge */
        if (trig_state != RISING) {
            finish();
            return;
        }
        trig_rose_late = 0;
        trig_fired = 1;
        trig_state = FALLING;
        r = (uint32_t)trig_width * 2;
    }
    aim(from, r);
}

#if ML_TIMING
/* timing_hardware_held (timing.c): a timed pulse due after `after`, taken and not yet begun
 * (waiting to be armed, or armed and its rising edge not made), dropped when `drop` */
static uint8_t held(uint8_t drop, uint8_t all, uint32_t after) {
    uint8_t n = 0;
    ATOMIC_BLOCK(ATOMIC_RESTORESTATE) {
        if (trig_timed && (trig_pending || trig_state == RISING) &&
            (all || (int32_t)(trig_tick - after) > 0)) {
            n = 1;
            if (drop) {
                trig_pending = 0;
                if (trig_state == RISING) finish();
            }
        }
    }
    return n;
}
#endif

void trigger_init(transducer_t *t, uint16_t pulse_us) {
#if ML_TIMING
    timing_hardware_held = held;
#endif
    trig_t = t;
    trig_pulse_us = pulse_us;
    PORTB &= (uint8_t)~_BV(TRIG_BIT);
    DDRB |= _BV(TRIG_BIT);
}

void trigger_set(uint16_t pulse_us) { trig_pulse_us = pulse_us; }

/* Arms the rising edge at trig_tick (board µs): 0 when that is less than MIN_STEP ticks away,
 * unless `now_ok`: then it is armed MIN_STEP ticks from now (trig_tick moved there), as it
 * always is with `now_ok` NOW (a pulse commanded now: trig_tick is not set). */
#define NOW 2
static uint8_t arm(uint8_t now_ok) {
    cli();
    uint32_t now = clock_ticks_from_isr(); /* TCNT2 = now mod 256 */
    int32_t r = (int32_t)(trig_tick * 2 - now); /* (ticks mod 2^32: hal.h) */
    if (r < MIN_STEP || now_ok == NOW) {
        if (!now_ok) {
            sei();
            return 0;
        }
        r = MIN_STEP;
        trig_tick = (now + MIN_STEP) >> 1; /* (the µs it is in) */
    }
    trig_state = RISING;
    TIMSK2 |= _BV(OCIE2A);
    aim((uint8_t)(now - 1), (uint32_t)r);
    sei();
    return 1;
}

static uint16_t width_of(const uint8_t *in, uint8_t n) {
    uint16_t w = n == 2 ? (uint16_t)(in[0] | (in[1] << 8)) : 0;
    return w ? w : trig_pulse_us;
}

uint8_t trigger_command(const uint8_t *in, uint8_t n, uint8_t *out, uint8_t *out_n) {
    /* now: the rising edge MIN_STEP ticks from when it is armed (from a clock read before, the
     * time taken to get there could use the lead up, and arm refused: no pulse at all) */
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
    arm(NOW);
    return 0;
}

#if ML_TIMING
uint8_t trigger_at(const uint8_t *payload, uint8_t n, uint32_t tick) {
    if (trig_state != IDLE || trig_pending || n != 2) return 0; /* timing.c queues it */
    trig_width = width_of(payload, n);
    trig_tick = tick;
    trig_pending = 1;
    trig_timed = 1;
    return 1;
}
#endif

void trigger_poll(uint32_t now) {
    if (trig_fired) {
        trig_fired = 0;
        trigger_pulses++;
#if ML_TIMING
        if (trig_timed) timing_done++;
#endif
        record(trig_t, 0, trig_width, trig_tick + trig_rose_late / 2); /* where the edge was */
    }
    if (!trig_pending || (int32_t)(trig_tick - now) > (int32_t)ARM_US) return;
    trig_pending = 0;
    if (!arm(0)) { /* the loop came too late: now, late by that much, and counted */
        trigger_late++;
        arm(1);
    }
}
