/* The HC-SR04: the same keys and arithmetic as board/drivers/hcsr04.py (Python), which says
 * what the module does.  On AVR the echo is not waited for: its edges are stamped by the pin's
 * pin-change interrupt (Timer1's count, so to the half µs), and the loop goes on meanwhile. */
#include "hcsr04.h"

#include <avr/interrupt.h>
#include <avr/io.h>
#include <avr/pgmspace.h>
#include <util/delay.h>

#include "hal.h"
#include "log.h"
#include "schedule.h"

#define MIN_MM 20
static transducer_t *ht;
static pin_t trig_pin, echo_pin;
static schedule_t hs;
static float temperature;
static uint16_t max_range;
static uint32_t deadline; /* board µs (hal.h) */
static volatile uint8_t state; /* 0 idle, 1 waiting for the echo to rise, 2 to fall, 3 done */
static volatile uint32_t rise_w, fall_w;
static volatile uint16_t rise_t, fall_t;
uint16_t hcsr04_timeouts;

void hcsr04_init(transducer_t *t, pin_t trig, pin_t echo, uint8_t pcie, volatile uint8_t *pcmsk,
                 float rate_hz, float temperature_c, uint16_t max_range_cm) {
    ht = t;
    trig_pin = trig;
    echo_pin = echo;
    pin_output(&trig_pin, 0);
    pin_input(&echo_pin);
    *pcmsk |= echo.mask;
    PCICR |= (uint8_t)(1 << pcie);
    hcsr04_set(rate_hz, temperature_c, max_range_cm);
}

void hcsr04_set(float rate_hz, float temperature_c, uint16_t max_range_cm) {
    sched_rate(&hs, rate_hz > 16.6f ? 16.6f : rate_hz);
    temperature = temperature_c;
    max_range = max_range_cm;
}

void hcsr04_align(uint8_t aligned, float phase) { sched_align(&hs, aligned, phase); }

void hcsr04_edge(void) {
    uint16_t t = TCNT1;
    uint32_t w = clock_wraps_at(t);
    uint8_t level = pin_read(&echo_pin);
    if (state == 1 && level) {
        rise_w = w;
        rise_t = t;
        state = 2;
    } else if (state == 2 && !level) {
        fall_w = w;
        fall_t = t;
        state = 3;
    }
}

static float sound(void) { return 331.3f + 0.606f * temperature; }

void hcsr04_poll(uint32_t now) {
    if (!ht) return;
    if (state == 3) {
        uint32_t rise = clock_at(rise_w, rise_t), fall = clock_at(fall_w, fall_t);
        state = 0;
        uint32_t width = (uint32_t)(fall - rise);
        uint32_t mm = (uint32_t)((float)width * sound() / 2000.0f + 0.5f);
        if (mm < MIN_MM || mm > (uint32_t)max_range * 10) record_na(ht, 0, fall);
        else record(ht, 0, mm, fall - width / 2);
        return;
    }
    if (state) {
        if ((int32_t)(now - deadline) > 0) { /* no echo, or none that ended within the range */
            /* (a module always answers a trigger: no echo at all is an absent one) */
            if (state == 1) log_fault_P(ht->tid, FAULT_NO_ANSWER, 0);
            state = 0;
            hcsr04_timeouts++;
            record_na(ht, 0, now);
        }
        return;
    }
    if (!sched_due(&hs, &now)) return;
    sched_wait(&hs, &now);
    pin_set(&trig_pin, 1);
    _delay_us(10);
    cli();
    pin_set(&trig_pin, 0);
    state = 1;
    sei();
    /* the round trip to max_range, and 1 ms for the burst before the echo rises */
    deadline = now + (uint32_t)(2.0f * max_range / 100.0f / sound() * 1e6f) + 1000;
}
