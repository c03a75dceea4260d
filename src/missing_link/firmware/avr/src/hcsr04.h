/* The HC-SR04 ultrasonic ranger (hcsr04.c; board/drivers/hcsr04.py). */
#ifndef J2A_HCSR04_H
#define J2A_HCSR04_H
#include <stdint.h>

#include "pins.h"
#include "runtime.h"

/* echo: any pin with a pin-change interrupt; pcie: its PCICR bit, pcmsk: its mask register */
void hcsr04_init(transducer_t *t, pin_t trig, pin_t echo, uint8_t pcie, volatile uint8_t *pcmsk,
                 float rate_hz, float temperature_c, uint16_t max_range_cm);
void hcsr04_set(float rate_hz, float temperature_c, uint16_t max_range_cm);
void hcsr04_align(uint8_t aligned, float phase);
void hcsr04_edge(void); /* the echo pin's pin-change interrupt (board_gen.c's ISR) */
void hcsr04_poll(uint32_t now);
extern uint16_t hcsr04_timeouts;
#endif
