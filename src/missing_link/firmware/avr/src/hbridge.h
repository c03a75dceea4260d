/* DC motors through H-bridges on Timer0 (hbridge.c; board/drivers/hbridge.py). */
#ifndef J2A_HBRIDGE_H
#define J2A_HBRIDGE_H
#include <stdint.h>

#include "pins.h"
#include "runtime.h"

/* out: 0 OC0A, 1 OC0B (PWM/DIR bridges, `dir` their direction pin), 2 both (IN1/IN2) */
void hbridge_init(uint8_t i, transducer_t *t, uint8_t out, pin_t dir, float ramp, uint8_t brake,
                  uint8_t invert, uint32_t freq);
void hbridge_set(uint8_t i, float ramp, uint8_t brake, uint32_t freq);
uint8_t hbridge_command(uint8_t i, const uint8_t *in, uint8_t n, uint8_t *out, uint8_t *out_n);
void hbridge_poll(uint8_t i, uint32_t now);
void hbridge_make_safe(uint8_t i);
#endif
