/* The quadrature encoder (drivers.h): the MicroPython driver's behaviour (board/drivers/, Python), which says
 * what the datasheet asks; the comments here say only what differs on this hardware. */
#include <avr/interrupt.h>
#include <avr/io.h>
#include <avr/pgmspace.h>

#include "drivers.h"
#include "hal.h"
#include "log.h"
#include "schedule.h"

/* ---- quadrature: INT0/INT1 on any edge, x4 decoding ------------------------------------------ */
#if defined(__AVR_ATmega328P__)
#define QUAD_PIN PIND
#define QUAD_PORT PORTD
#define QUAD_A PD2 /* Uno D2 */
#define QUAD_B PD3 /* Uno D3 */
#else /* ATmega2560 (Mega D21/D20), ATmega32U4 (Leonardo D3/D2) */
#define QUAD_PIN PIND
#define QUAD_PORT PORTD
#define QUAD_A PD0
#define QUAD_B PD1
#endif

static const int8_t quad_step[16] PROGMEM = {0, -1, 1, 0, 1, 0, 0, -1, -1, 0, 0, 1, 0, 1, -1, 0};
static transducer_t *quad_t;
static volatile int32_t quad_count;
static volatile uint8_t quad_state, quad_bad, quad_moved;
static volatile uint32_t quad_edge_us;
static int8_t quad_sign = 1;
static schedule_t quad_s;
volatile uint16_t quadrature_errors;

static uint8_t quad_read(void) {
    uint8_t p = QUAD_PIN;
    return (uint8_t)((((p >> QUAD_A) & 1) << 1) | ((p >> QUAD_B) & 1));
}

static void quad_edge(void) {
    uint8_t s = quad_read(), prev = quad_state;
    if (s == prev) return;
    quad_state = s;
    int8_t d = (int8_t)pgm_read_byte(&quad_step[(prev << 2) | s]);
    if (d == 0) { /* both phases changed: an edge was missed */
        quadrature_errors++;
        quad_bad = 1;
        return;
    }
    quad_count += d * quad_sign;
    quad_edge_us = clock_now_from_isr(); /* stamped in the interrupt */
    quad_moved = 1;
}

ISR(INT0_vect) { quad_edge(); }
ISR(INT1_vect) { quad_edge(); }

void quadrature_init(transducer_t *t, uint16_t rate_hz, uint8_t reverse) {
    quad_t = t;
    quad_sign = reverse ? -1 : 1;
    quad_s.period_us = 1000000UL / rate_hz;
    QUAD_PORT |= _BV(QUAD_A) | _BV(QUAD_B); /* pull-ups for open-collector outputs */
    quad_state = quad_read();
    EICRA = _BV(ISC00) | _BV(ISC10); /* any logical change */
    EIMSK = _BV(INT0) | _BV(INT1);
}

void quadrature_set(float rate_hz, uint8_t reverse) {
    sched_rate(&quad_s, rate_hz);
    quad_sign = reverse ? -1 : 1;
}

void quadrature_align(uint8_t aligned, float phase) { sched_align(&quad_s, aligned, phase); }

void quadrature_poll(uint32_t now) {
    if (!quad_t || !sched_due(&quad_s, &now)) return;
    sched_wait(&quad_s, &now);
    int32_t count;
    uint32_t stamp;
    uint8_t bad, moved;
    cli();
    count = quad_count;
    stamp = quad_edge_us;
    bad = quad_bad;
    moved = quad_moved;
    quad_bad = quad_moved = 0;
    sei();
    if (bad) {
        log_fault_P(quad_t->tid, FAULT_OVERRUN, 0);
        record_na(quad_t, 0, now);
    }
    else record(quad_t, 0, (uint32_t)count, moved ? stamp : now);
}

