/* The Sharp GP2Y0A02YK0F IR ranger (drivers.h): the MicroPython driver's behaviour (board/drivers/, Python), which says
 * what the datasheet asks; the comments here say only what differs on this hardware. */
#include <avr/io.h>
#include <avr/pgmspace.h>

#include "drivers.h"
#include "hal.h"
#include "schedule.h"

/* ---- Sharp GP2Y0A02YK0F on the ADC (AVcc = 5 V reference, 10 bit) ----------------------------- */
static const uint16_t sharp_mv[] PROGMEM = {2500, 2000, 1550, 1250, 1050, 900, 800,
                                    720,  650,  600,  550,  500,  450,  410};
static const uint16_t sharp_mm[] PROGMEM = {200, 300, 400, 500, 600, 700, 800,
                                    900, 1000, 1100, 1200, 1300, 1400, 1500};
#define SHARP_POINTS (sizeof sharp_mv / sizeof sharp_mv[0])
static transducer_t *sharp_t;
static uint8_t sharp_channel;
static schedule_t sharp_s;
static uint32_t sharp_start;
static uint8_t sharp_warm; /* 50 ms since it was powered: its first reading is good */

void sharp_init(transducer_t *t, uint8_t adc_channel, uint16_t rate_hz) {
    sharp_t = t;
    sharp_channel = adc_channel & 7;
    if (rate_hz > 26) rate_hz = 26; /* the sensor updates every 38 ms */
    sharp_s.period_us = 1000000UL / rate_hz;
    ADCSRA = _BV(ADEN) | _BV(ADPS2) | _BV(ADPS1) | _BV(ADPS0); /* 125 kHz ADC clock */
    sharp_start = clock_now();
}

void sharp_set(float rate_hz) { sched_rate(&sharp_s, rate_hz); }

void sharp_align(uint8_t aligned, float phase) { sched_align(&sharp_s, aligned, phase); }

static uint16_t adc_convert(void) {
    ADCSRA |= _BV(ADSC);
    while (ADCSRA & _BV(ADSC)) {
    }
    return ADC;
}

/* mm for a voltage on the datasheet curve, interpolated in 1/distance; 0 = outside */
#define MV(i) pgm_read_word(&sharp_mv[i])
#define MM(i) pgm_read_word(&sharp_mm[i])
static uint16_t sharp_volts_to_mm(uint16_t mv) {
    if (mv > MV(0) || mv < MV(SHARP_POINTS - 1)) return 0;
    for (uint8_t i = 1; i < SHARP_POINTS; i++) {
        if (mv >= MV(i)) {
            float f = (float)(MV(i - 1) - mv) / (float)(MV(i - 1) - MV(i));
            float inv = 1.0f / MM(i - 1) + f * (1.0f / MM(i) - 1.0f / MM(i - 1));
            return (uint16_t)(1.0f / inv + 0.5f);
        }
    }
    return 0;
}

void sharp_poll(uint32_t now) {
    if (!sharp_t || !sched_due(&sharp_s, &now)) return;
    ADMUX = _BV(REFS0) | sharp_channel; /* AVcc */
    if (!sharp_warm) sharp_warm = now - sharp_start >= 50000UL;
    uint8_t warm = sharp_warm;
    sched_wait(&sharp_s, &now); /* the first conversion starts on the instant */
    if (!warm) {
        record_na(sharp_t, 0, now);
        return;
    }
    uint16_t a = adc_convert(), b = adc_convert(), c = adc_convert();
    uint16_t med = a > b ? (b > c ? b : (a > c ? c : a)) : (a > c ? a : (b > c ? c : b));
    uint16_t mm = sharp_volts_to_mm((uint16_t)((uint32_t)med * 5000UL / 1023UL));
    if (mm) record(sharp_t, 0, mm, now);
    else record_na(sharp_t, 0, now);
}

