/* The servo on OC1A (drivers.h): the MicroPython driver's behaviour (board/drivers/, Python), which says
 * what the datasheet asks; the comments here say only what differs on this hardware. */
#include <avr/io.h>

#include "drivers.h"
#include "hal.h"

/* ---- servo on OC1A (Timer1's 50 Hz frame) ----------------------------------------------------- */
#if defined(__AVR_ATmega328P__)
#define SERVO_DDR DDRB
#define SERVO_BIT PB1 /* Uno D9 */
#else
#define SERVO_DDR DDRB
#define SERVO_BIT PB5 /* Mega D11, Leonardo D9 */
#endif
static transducer_t *servo_t;
static uint16_t servo_min, servo_max, servo_centre, servo_half;
uint16_t servo_commands;

static int8_t servo_value;
static uint8_t servo_on, servo_limp; /* servo_limp: the failsafe's `safe` = limp */

void servo_init(transducer_t *t, uint16_t min_us, uint16_t max_us, uint16_t centre_us,
                uint16_t span_us, uint8_t limp) {
    servo_t = t;
    servo_min = min_us;
    servo_max = max_us;
    servo_centre = centre_us;
    servo_half = span_us / 2;
    servo_limp = limp;
}

static void servo_pulse(void) {
    int8_t v = servo_value;
    int32_t us = (int32_t)servo_centre + ((int32_t)v * servo_half + (v >= 0 ? 63 : -63)) / 127;
    if (us < servo_min) us = servo_min;
    if (us > servo_max) us = servo_max;
    OCR1A = (uint16_t)(us * 2); /* 0.5 µs ticks */
}

void servo_set(uint16_t min_us, uint16_t max_us, uint16_t centre_us, uint16_t span_us,
               uint8_t limp) {
    servo_init(servo_t, min_us, max_us, centre_us, span_us, limp);
    if (servo_on) servo_pulse(); /* a pulse already out: re-clamped to the new limits */
}

void servo_make_safe(void) {
    /* the failsafe (failsafe.c): hold the last pulse, or stop the pulses (limp, N/A) */
    if (servo_limp && servo_on) {
        TCCR1A &= (uint8_t)~_BV(COM1A1);
        PORTB &= (uint8_t)~_BV(SERVO_BIT); /* (OC1A is on port B on every MCU here) */
        servo_on = 0;
    }
    if (servo_on) record(servo_t, 0, (uint8_t)servo_value, clock_now());
    else record_na(servo_t, 0, clock_now());
}

uint8_t servo_command(const uint8_t *in, uint8_t n, uint8_t *out, uint8_t *out_n) {
    *out_n = 0;
    if (n != 1 || (int8_t)in[0] == -128) return 0xFF;
    int8_t v = (int8_t)in[0];
    servo_value = v;
    servo_on = 1;
    servo_pulse();
    uint16_t us = OCR1A / 2;
    SERVO_DDR |= _BV(SERVO_BIT);
    TCCR1A |= _BV(COM1A1); /* the pulse starts with the next frame */
    servo_commands++;
    record(servo_t, 0, (uint8_t)v, clock_now());
    out[0] = (uint8_t)us;
    out[1] = (uint8_t)(us >> 8);
    *out_n = 2;
    return 0;
}
