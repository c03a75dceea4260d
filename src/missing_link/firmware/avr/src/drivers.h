/* Drivers for the thesis rig on AVR: the same names and behaviour as the MicroPython drivers
 * (board/drivers/ (Python)).  One instance of each (they own fixed hardware: Timer1's OC1A,
 * Timer2's OC2A, the TWI's SRF02 state); the generator refuses a second.  The encoders:
 * quadrature.h. */
#ifndef J2A_DRIVERS_H
#define J2A_DRIVERS_H
#include <stdint.h>

#include "runtime.h"

void sharp_init(transducer_t *t, uint8_t adc_channel, uint16_t rate_hz);
void sharp_set(float rate_hz);
void sharp_align(uint8_t aligned, float phase);
void sharp_poll(uint32_t now);

void srf02_init(transducer_t *t, uint8_t address, uint16_t rate_hz, uint8_t min_range_cm);
void srf02_set(float rate_hz, uint16_t min_range_cm);
void srf02_align(uint8_t aligned, float phase);
void srf02_poll(uint32_t now);
extern uint16_t srf02_timeouts, srf02_bus_errors;

void servo_init(transducer_t *t, uint16_t min_us, uint16_t max_us, uint16_t centre_us,
                uint16_t span_us, uint8_t limp);
void servo_set(uint16_t min_us, uint16_t max_us, uint16_t centre_us, uint16_t span_us,
               uint8_t limp);
void servo_make_safe(void);
uint8_t servo_command(const uint8_t *in, uint8_t n, uint8_t *out, uint8_t *out_n);

/* A trigger output on the MCU's fixed pin (Uno D10, Mega D10): a pulse when commanded, or at a
 * board tick through Timer2's compare (a timed call, timing.c), within a timer tick of it. */
void trigger_init(transducer_t *t, uint16_t pulse_us);
void trigger_set(uint16_t pulse_us);
uint8_t trigger_command(const uint8_t *in, uint8_t n, uint8_t *out, uint8_t *out_n);
uint8_t trigger_at(const uint8_t *payload, uint8_t n, uint32_t tick); /* 1: armed */
void trigger_poll(uint32_t now);
#endif
