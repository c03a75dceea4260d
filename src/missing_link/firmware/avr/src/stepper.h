/* A stepper through a step/dir driver (stepper.c; board/drivers/stepper.py). */
#ifndef J2A_STEPPER_H
#define J2A_STEPPER_H
#include <stdint.h>

#include "pins.h"
#include "runtime.h"

void stepper_init(transducer_t *t, pin_t step, pin_t dir, pin_t enable, uint8_t has_enable,
                  uint16_t per_rev, float max_speed, float accel, uint8_t velocity,
                  uint8_t invert);
void stepper_set(float max_speed, float accel, uint8_t velocity);
uint8_t stepper_command(const uint8_t *in, uint8_t n, uint8_t *out, uint8_t *out_n);
void stepper_poll(uint32_t now);
void stepper_make_safe(void);
#endif
