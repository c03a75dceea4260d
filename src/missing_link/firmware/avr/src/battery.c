/* The battery driver on AVR: see board/drivers/battery.py for what it measures and why; the
 * comments here say only what differs on this hardware.  The reference is AVcc, whose voltage
 * is the board file's `vref` (5.0 on an Uno or a Mega); a code is vref / 1023 volts a step (full
 * scale = vref, as read_u16 on MicroPython), 10 bits. */
#include "battery.h"

#include <avr/io.h>
#include <avr/pgmspace.h>

#include "schedule.h"

static transducer_t *bt;
static schedule_t bs;
static uint8_t b_channel, b_cells, b_chemistry, b_reads;
static float b_lsb, b_ratio; /* volts a code at the pin; the divider's ratio */
static const float *b_points;
static const uint8_t *b_starts;

void battery_init(transducer_t *t, uint8_t adc_channel, float rate_hz, float vref, float ratio,
                  uint8_t cells, uint8_t chemistry, uint8_t reads, const float *points,
                  const uint8_t *starts) {
    bt = t;
    b_channel = adc_channel & 7;
    b_lsb = vref / 1023.0f;
    b_reads = reads < 1 ? 1 : (reads > BATTERY_MAX_READS ? BATTERY_MAX_READS : reads);
    b_points = points;
    b_starts = starts;
    battery_set(rate_hz, ratio, cells, chemistry);
    ADCSRA = _BV(ADEN) | _BV(ADPS2) | _BV(ADPS1) | _BV(ADPS0); /* 125 kHz ADC clock */
}

void battery_set(float rate_hz, float ratio, uint8_t cells, uint8_t chemistry) {
    sched_rate(&bs, rate_hz);
    b_ratio = ratio;
    b_cells = cells;
    b_chemistry = chemistry;
}

void battery_align(uint8_t aligned, float phase) { sched_align(&bs, aligned, phase); }

/* the charge at `volts` a cell on the chemistry's curve, linear between points, clamped */
#define PV(i) pgm_read_float(&b_points[2 * (i)])
#define PF(i) pgm_read_float(&b_points[2 * (i) + 1])
static float battery_charge(float volts) {
    uint8_t first = b_starts[b_chemistry], end = b_starts[b_chemistry + 1];
    if (volts <= PV(first)) return PF(first);
    for (uint8_t k = first + 1; k < end; k++) {
        float v1 = PV(k);
        if (volts <= v1) {
            float v0 = PV(k - 1), f0 = PF(k - 1);
            return f0 + (PF(k) - f0) * (volts - v0) / (v1 - v0);
        }
    }
    return PF(end - 1);
}

static void put(uint8_t ch, float v, uint32_t now) {
    uint32_t raw;
    __builtin_memcpy(&raw, &v, 4);
    record(bt, ch, raw, now);
}

void battery_poll(uint32_t now) {
    if (!bt || !sched_due(&bs, &now)) return;
    ADMUX = _BV(REFS0) | b_channel; /* AVcc */
    sched_wait(&bs, &now); /* the first conversion starts on the instant */
    uint16_t r[BATTERY_MAX_READS];
    for (uint8_t i = 0; i < b_reads; i++) { /* insertion sort as they come: the median */
        ADCSRA |= _BV(ADSC);
        while (ADCSRA & _BV(ADSC)) {
        }
        uint16_t a = ADC;
        uint8_t j = i;
        for (; j > 0 && r[j - 1] > a; j--) r[j] = r[j - 1];
        r[j] = a;
    }
    uint16_t raw = r[b_reads / 2];
    if (raw == 0) { /* code 0 (the Python driver's < 16 of 65535): nothing on the pin */
        record_na(bt, 0, now);
        record_na(bt, 1, now);
        return;
    }
    float volts = raw * b_lsb * b_ratio;
    put(0, volts, now);
    put(1, battery_charge(volts / b_cells), now);
}
