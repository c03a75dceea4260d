/* Quadrature encoders (quadrature.h): the MicroPython driver's behaviour (board/drivers/encoder.py),
 * which says what the datasheet asks; the comments here say only what differs on this hardware.
 * x4 decoding in the interrupt of either phase's pin, stamped there. */
#include "quadrature.h"

#include <avr/interrupt.h>
#include <avr/pgmspace.h>

#include "hal.h"
#include "log.h"

static const int8_t quad_step[16] PROGMEM = {0, -1, 1, 0, 1, 0, 0, -1, -1, 0, 0, 1, 0, 1, -1, 0};
volatile uint16_t quadrature_errors;

static uint8_t quad_read(const quadrature_t *q) {
    return (uint8_t)((pin_read(&q->a) << 1) | pin_read(&q->b));
}

void quadrature_edge(quadrature_t *q) {
    /* stamped first: the stamp is late by this routine's entry (about 4 µs), and by any routine
     * that held its interrupt off (an encoder's takes 238 cycles on an Uno, 15 µs: rig's irqoff) */
    uint32_t now = clock_now_from_isr();
    uint8_t s = quad_read(q), prev = q->state;
    if (s == prev) return; /* (another pin of a shared pin-change interrupt) */
    q->state = s;
    int8_t d = (int8_t)pgm_read_byte(&quad_step[(prev << 2) | s]);
    if (d == 0) { /* both phases changed: an edge was missed */
        quadrature_errors++;
        q->bad = 1;
        return;
    }
    if (q->sign < 0) d = (int8_t)-d; /* (not a multiply: avr-gcc calls a 32-bit one) */
    q->count += d;
    q->edge_us = now;
    q->moved = 1;
}

void quadrature_init(quadrature_t *q, transducer_t *t, pin_t a, pin_t b, uint16_t rate_hz,
                     uint8_t reverse) {
    q->t = t;
    q->a = a;
    q->b = b;
    q->sign = reverse ? -1 : 1;
    q->s.period_us = 1000000UL / rate_hz;
    pin_set(&a, 1); /* pull-ups for open-collector outputs (an input with its PORT bit set) */
    pin_set(&b, 1);
    q->state = quad_read(q);
}

void quadrature_set(quadrature_t *q, float rate_hz, uint8_t reverse) {
    sched_rate(&q->s, rate_hz);
    q->sign = reverse ? -1 : 1;
}

void quadrature_align(quadrature_t *q, uint8_t aligned, float phase) {
    sched_align(&q->s, aligned, phase);
}

void quadrature_poll(quadrature_t *q, uint32_t now) {
    if (!sched_due(&q->s, &now)) return;
    sched_wait(&q->s, &now);
    int32_t count;
    uint32_t stamp;
    uint8_t bad, moved;
    cli();
    count = q->count;
    stamp = q->edge_us;
    bad = q->bad;
    moved = q->moved;
    q->bad = q->moved = 0;
    sei();
    if (bad) {
        log_fault_P(q->t->tid, FAULT_OVERRUN, 0);
        record_na(q->t, 0, now);
    }
    else record(q->t, 0, (uint32_t)count, moved ? stamp : now);
}
