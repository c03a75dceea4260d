/* Thesis-rig drivers for AVR.  See board/drivers/ (Python) for the datasheet behaviour each follows;
 * the comments here say only what differs on this hardware. */
#include "drivers.h"

#include <avr/interrupt.h>
#include <avr/io.h>
#include <avr/pgmspace.h>
#include <util/twi.h>

#include "hal.h"
#include "log.h"
#include "schedule.h"
#include "timing.h"

/* ---- quadrature: INT0/INT1 on any edge, x4 decoding ------------------------------------------ */
#if defined(__AVR_ATmega328P__)
#define QUAD_PIN PIND
#define QUAD_PORT PORTD
#define QUAD_A PD2 /* Uno D2 */
#define QUAD_B PD3 /* Uno D3 */
#else /* ATmega2560 (Mega D21/D20), ATmega32U4 (Leonardo D3/D2) */
#define QUAD_PIN PIND
#define QUAD_PORT PORTD
#define QUAD_A PD0
#define QUAD_B PD1
#endif

static const int8_t quad_step[16] PROGMEM = {0, -1, 1, 0, 1, 0, 0, -1, -1, 0, 0, 1, 0, 1, -1, 0};
static transducer_t *quad_t;
static volatile int32_t quad_count;
static volatile uint8_t quad_state, quad_bad, quad_moved;
static volatile uint64_t quad_edge_us;
static int8_t quad_sign = 1;
static schedule_t quad_s;
volatile uint16_t quadrature_errors;

static uint8_t quad_read(void) {
    uint8_t p = QUAD_PIN;
    return (uint8_t)((((p >> QUAD_A) & 1) << 1) | ((p >> QUAD_B) & 1));
}

static void quad_edge(void) {
    uint8_t s = quad_read(), prev = quad_state;
    if (s == prev) return;
    quad_state = s;
    int8_t d = (int8_t)pgm_read_byte(&quad_step[(prev << 2) | s]);
    if (d == 0) { /* both phases changed: an edge was missed */
        quadrature_errors++;
        quad_bad = 1;
        return;
    }
    quad_count += d * quad_sign;
    quad_edge_us = board_clock_from_isr(); /* stamped in the interrupt */
    quad_moved = 1;
}

ISR(INT0_vect) { quad_edge(); }
ISR(INT1_vect) { quad_edge(); }

void quadrature_init(transducer_t *t, uint16_t rate_hz, uint8_t reverse) {
    quad_t = t;
    quad_sign = reverse ? -1 : 1;
    quad_s.period_us = 1000000UL / rate_hz;
    QUAD_PORT |= _BV(QUAD_A) | _BV(QUAD_B); /* pull-ups for open-collector outputs */
    quad_state = quad_read();
    EICRA = _BV(ISC00) | _BV(ISC10); /* any logical change */
    EIMSK = _BV(INT0) | _BV(INT1);
}

void quadrature_set(float rate_hz, uint8_t reverse) {
    sched_rate(&quad_s, rate_hz);
    quad_sign = reverse ? -1 : 1;
}

void quadrature_align(uint8_t aligned, float phase) { sched_align(&quad_s, aligned, phase); }

void quadrature_poll(uint64_t now) {
    if (!quad_t || !sched_due(&quad_s, &now)) return;
    sched_wait(&quad_s, &now);
    int32_t count;
    uint64_t stamp;
    uint8_t bad, moved;
    cli();
    count = quad_count;
    stamp = quad_edge_us;
    bad = quad_bad;
    moved = quad_moved;
    quad_bad = quad_moved = 0;
    sei();
    if (bad) {
        log_fault_P(quad_t->tid, FAULT_OVERRUN, 0);
        record_na(quad_t, 0, now);
    }
    else record(quad_t, 0, (uint32_t)count, moved ? stamp : now);
}

/* ---- Sharp GP2Y0A02YK0F on the ADC (AVcc = 5 V reference, 10 bit) ----------------------------- */
static const uint16_t sharp_mv[] PROGMEM = {2500, 2000, 1550, 1250, 1050, 900, 800,
                                    720,  650,  600,  550,  500,  450,  410};
static const uint16_t sharp_mm[] PROGMEM = {200, 300, 400, 500, 600, 700, 800,
                                    900, 1000, 1100, 1200, 1300, 1400, 1500};
#define SHARP_POINTS (sizeof sharp_mv / sizeof sharp_mv[0])
static transducer_t *sharp_t;
static uint8_t sharp_channel;
static schedule_t sharp_s;
static uint64_t sharp_start;

void sharp_init(transducer_t *t, uint8_t adc_channel, uint16_t rate_hz) {
    sharp_t = t;
    sharp_channel = adc_channel & 7;
    if (rate_hz > 26) rate_hz = 26; /* the sensor updates every 38 ms */
    sharp_s.period_us = 1000000UL / rate_hz;
    ADCSRA = _BV(ADEN) | _BV(ADPS2) | _BV(ADPS1) | _BV(ADPS0); /* 125 kHz ADC clock */
    sharp_start = board_clock();
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

void sharp_poll(uint64_t now) {
    if (!sharp_t || !sched_due(&sharp_s, &now)) return;
    ADMUX = _BV(REFS0) | sharp_channel; /* AVcc */
    uint8_t warm = now - sharp_start >= 50000UL;
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

/* ---- SRF02 on TWI (100 kHz master, every wait bounded) ---------------------------------------- */
static transducer_t *srf02_t;
static uint8_t srf02_addr, srf02_min;
static schedule_t srf02_s;
static uint64_t srf02_ping_us, srf02_check_us;
static uint8_t srf02_ranging;
uint16_t srf02_timeouts, srf02_bus_errors;

static uint8_t twi_wait(void) {
    for (uint16_t i = 0; i < 2000; i++) /* ~ 1 ms at 16 MHz: a stuck bus is an error, not a hang */
        if (TWCR & _BV(TWINT)) return 1;
    return 0;
}

static uint8_t twi_cmd(uint8_t cr) {
    TWCR = (uint8_t)(cr | _BV(TWINT) | _BV(TWEN));
    return twi_wait() ? TW_STATUS : 0xFF;
}

/* A step whose status must differ from the one before it (an address after a start; the
 * bytes of a read of at most 2: 0x40 -> 0x50 -> 0x58).  On a real TWI the new status is there
 * when TWINT is; simavr 1.6 can show TWINT a moment before it, so wait for both. */
static uint8_t twi_cmd_change(uint8_t cr) {
    uint8_t prev = TW_STATUS;
    TWCR = (uint8_t)(cr | _BV(TWINT) | _BV(TWEN));
    for (uint16_t i = 0; i < 2000; i++) {
        uint8_t st = TW_STATUS;
        if ((TWCR & _BV(TWINT)) && st != prev) return st;
    }
    return 0xFF;
}

static void twi_stop(void) { TWCR = _BV(TWINT) | _BV(TWEN) | _BV(TWSTO); }

/* Write reg, then (rn = 1 or 2) read rn bytes; 0 ok, 1 no acknowledge (busy), 2 bus error. */
static uint8_t twi_transfer(uint8_t reg, const uint8_t *w, uint8_t wn, uint8_t *r, uint8_t rn) {
    uint8_t st = twi_cmd(_BV(TWSTA));
    if (st != TW_START && st != TW_REP_START) goto bus;
    TWDR = (uint8_t)(srf02_addr << 1);
    st = twi_cmd_change(0);
    /* (simavr 1.6 reports an acknowledged address write as 0x28/0x30, data ACK/NACK; a real
     * TWI never does, so accepting both costs nothing) */
    if (st == TW_MT_SLA_NACK || st == TW_MT_DATA_NACK) {
        twi_stop();
        return 1;
    }
    if (st != TW_MT_SLA_ACK && st != TW_MT_DATA_ACK) goto bus;
    TWDR = reg;
    if (twi_cmd(0) != TW_MT_DATA_ACK) goto bus;
    for (uint8_t i = 0; i < wn; i++) {
        TWDR = w[i];
        if (twi_cmd(0) != TW_MT_DATA_ACK) goto bus;
    }
    if (rn) {
        st = twi_cmd(_BV(TWSTA));
        if (st != TW_REP_START && st != TW_START) goto bus; /* (simavr says START) */
        TWDR = (uint8_t)((srf02_addr << 1) | 1);
        st = twi_cmd_change(0);
        if (st == TW_MR_SLA_NACK) {
            twi_stop();
            return 1;
        }
        if (st != TW_MR_SLA_ACK) goto bus;
        for (uint8_t i = 0; i < rn; i++) {
            uint8_t last = i + 1 == rn;
            st = twi_cmd_change(last ? 0 : _BV(TWEA));
            if (st != TW_MR_DATA_NACK && st != TW_MR_DATA_ACK) goto bus; /* a byte came */
            r[i] = TWDR;
        }
    }
    twi_stop();
    return 0;
bus:
    twi_stop();
    return 2;
}

void srf02_init(transducer_t *t, uint8_t address, uint16_t rate_hz, uint8_t min_range_cm) {
    srf02_t = t;
    srf02_addr = address;
    srf02_min = min_range_cm;
    srf02_s.period_us = 1000000UL / rate_hz;
    if (srf02_s.period_us < 65000UL) srf02_s.period_us = 65000UL; /* a ranging takes 65 ms */
    TWSR = 0;
    TWBR = 72; /* 100 kHz at 16 MHz */
}

void srf02_set(float rate_hz, uint16_t min_range_cm) {
    sched_rate(&srf02_s, rate_hz < 15.38f ? rate_hz : 15.38f); /* a ranging takes 65 ms */
    srf02_min = (uint8_t)(min_range_cm > 255 ? 255 : min_range_cm);
}

void srf02_align(uint8_t aligned, float phase) { sched_align(&srf02_s, aligned, phase); }

void srf02_poll(uint64_t now) {
    if (!srf02_t) return;
    if (!srf02_ranging) {
        if (!sched_due(&srf02_s, &now)) return;
        const uint8_t cmd = 0x51; /* range in cm */
        sched_wait(&srf02_s, &now); /* the command starts on the instant */
        uint8_t st = twi_transfer(0, &cmd, 1, 0, 0);
        if (st != 0) { /* between rangings it answers: no acknowledge is an absent part */
            log_fault_P(srf02_t->tid, st == 1 ? FAULT_NO_ANSWER : FAULT_BUS, 0);
            srf02_bus_errors++;
            record_na(srf02_t, 0, now);
            return;
        }
        srf02_ping_us = board_clock();
        srf02_check_us = srf02_ping_us + 65000UL;
        srf02_ranging = 1;
        return;
    }
    if (now < srf02_check_us) return;
    uint8_t rev = 0xFF;
    uint8_t st = twi_transfer(0, 0, 0, &rev, 1);
    if (st == 2) {
        log_fault_P(srf02_t->tid, FAULT_BUS, 0);
        srf02_bus_errors++;
    }
    if (st != 0 || rev == 0xFF) { /* still ranging */
        if (now - srf02_ping_us >= 100000UL) {
            log_fault_P(srf02_t->tid, FAULT_TIMEOUT, 0);
            srf02_timeouts++;
            srf02_ranging = 0;
            record_na(srf02_t, 0, now);
        } else {
            srf02_check_us = now + 5000UL;
        }
        return;
    }
    srf02_ranging = 0;
    uint8_t r[2];
    if (twi_transfer(2, 0, 0, r, 2) != 0) {
        log_fault_P(srf02_t->tid, FAULT_BUS, 0);
        srf02_bus_errors++;
        record_na(srf02_t, 0, now);
        return;
    }
    uint16_t cm = (uint16_t)((r[0] << 8) | r[1]);
    if (cm == 0 || cm < srf02_min) record_na(srf02_t, 0, now);
    else record(srf02_t, 0, cm, srf02_ping_us + (uint32_t)cm * 583UL / 20UL); /* + half flight */
}

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
    if (servo_on) record(servo_t, 0, (uint8_t)servo_value, board_clock());
    else record_na(servo_t, 0, board_clock());
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
    record(servo_t, 0, (uint8_t)v, board_clock());
    out[0] = (uint8_t)us;
    out[1] = (uint8_t)(us >> 8);
    *out_n = 2;
    return 0;
}
