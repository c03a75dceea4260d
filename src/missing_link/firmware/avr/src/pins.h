/* Any digital pin, as the generator names it from the board file's Arduino pin number
 * (deploy/avrgen.py: PINx, DDRx and PORTx sit at consecutive addresses on these MCUs). */
#ifndef J2A_PINS_H
#define J2A_PINS_H
#include <stdint.h>

typedef struct {
    volatile uint8_t *port; /* PORTx; DDRx is port - 1, PINx port - 2 */
    uint8_t mask;
} pin_t;

static inline void pin_output(const pin_t *p, uint8_t level) {
    if (level) *p->port |= p->mask;
    else *p->port &= (uint8_t)~p->mask;
    *(p->port - 1) |= p->mask;
}

static inline void pin_input(const pin_t *p) { *(p->port - 1) &= (uint8_t)~p->mask; }

static inline void pin_set(const pin_t *p, uint8_t level) {
    if (level) *p->port |= p->mask;
    else *p->port &= (uint8_t)~p->mask;
}

static inline uint8_t pin_read(const pin_t *p) { return (*(p->port - 2) & p->mask) != 0; }
#endif
