/* Quadrature encoders (quadrature.c): the MicroPython driver's behaviour (board/drivers/encoder.py),
 * as many as the board has interrupts for.  Each phase's pin interrupts on any change: an
 * external interrupt (INTn) or a pin-change interrupt (PCINTn, shared with the other pins of its
 * port); board_gen.c enables them and its interrupt routines call quadrature_edge for the
 * encoders on that pin (deploy/avrpins.py says which pins have which). */
#ifndef J2A_QUADRATURE_H
#define J2A_QUADRATURE_H
#include <stdint.h>

#include "pins.h"
#include "runtime.h"
#include "schedule.h"

typedef struct {
    transducer_t *t;
    pin_t a, b;
    schedule_t s;
    volatile int32_t count;
    volatile uint32_t edge_us; /* the newest edge that moved it (board µs, hal.h) */
    volatile uint8_t state, bad, moved;
    int8_t sign;
} quadrature_t;

/* pulled up (open-collector outputs), its state read; its interrupts are board_gen.c's */
void quadrature_init(quadrature_t *q, transducer_t *t, pin_t a, pin_t b, uint16_t rate_hz,
                     uint8_t reverse);
void quadrature_edge(quadrature_t *q); /* a phase may have changed (its pin's interrupt) */
void quadrature_set(quadrature_t *q, float rate_hz, uint8_t reverse); /* (config.c) */
void quadrature_align(quadrature_t *q, uint8_t aligned, float phase); /* (timing.c's grid) */
void quadrature_poll(quadrature_t *q, uint32_t now);
extern volatile uint16_t quadrature_errors; /* edges missed, all encoders */
#endif
