/* DC motors through H-bridges: the same keys and behaviour as board/drivers/hbridge.py
 * (Python), which says what the bridges do.  Timer0 makes the PWM (fast PWM, 8 bit) on OC0A
 * (Uno D6, Mega D13) and OC0B (Uno D5, Mega D4): two PWM/DIR bridges (one output each, the
 * direction on any pin), or one IN1/IN2 bridge (IN1 on OC0A, IN2 on OC0B).  `freq` takes the
 * prescaler nearest to it: 62.5 kHz, 7.8 kHz, 977 Hz, 244 Hz or 61 Hz.  Duty 0 and full duty
 * hand the pin to PORT (low, high): fast PWM would leave a 1/256 spike at OCR = 0. */
#include "hbridge.h"

#include <avr/io.h>

#include "hal.h"

#if defined(__AVR_ATmega328P__)
#define OC0A_PORT PORTD
#define OC0A_DDR DDRD
#define OC0A_BIT PD6
#define OC0B_PORT PORTD
#define OC0B_DDR DDRD
#define OC0B_BIT PD5
#else /* ATmega2560 */
#define OC0A_PORT PORTB
#define OC0A_DDR DDRB
#define OC0A_BIT PB7
#define OC0B_PORT PORTG
#define OC0B_DDR DDRG
#define OC0B_BIT PG5
#endif
#define RAMP_STEP_US 20000UL

typedef struct {
    transducer_t *t;
    uint8_t out; /* 0: OC0A, 1: OC0B, 2: both (IN1/IN2) */
    pin_t dir;
    uint8_t brake, invert;
    float target, duty, ramp;
    uint32_t last_us, due; /* board µs (hal.h) */
    uint8_t ramping;       /* due: the ramp's next step */
} hbridge_t;

static hbridge_t motors[2];
static const uint16_t prescale[] = {1, 8, 64, 256, 1024};

static void out_set(uint8_t which, uint8_t v) {
    uint8_t com = which ? _BV(COM0B1) : _BV(COM0A1);
    if (v == 0 || v == 255) {
        TCCR0A &= (uint8_t)~com; /* the pin is PORT's: low or high */
        if (which) {
            if (v) OC0B_PORT |= _BV(OC0B_BIT);
            else OC0B_PORT &= (uint8_t)~_BV(OC0B_BIT);
        } else {
            if (v) OC0A_PORT |= _BV(OC0A_BIT);
            else OC0A_PORT &= (uint8_t)~_BV(OC0A_BIT);
        }
        return;
    }
    if (which) OCR0B = v;
    else OCR0A = v;
    TCCR0A |= com;
}

static void apply(hbridge_t *m, float d) {
    if (m->invert) d = -d;
    float a = d < 0 ? -d : d;
    uint8_t v = (uint8_t)(a * 255.0f + 0.5f);
    if (m->out < 2) {
        pin_set(&m->dir, d < 0);
        out_set(m->out, v);
    } else if (v == 0) {
        out_set(0, m->brake ? 255 : 0);
        out_set(1, m->brake ? 255 : 0);
    } else if (d > 0) {
        out_set(1, 0);
        out_set(0, v);
    } else {
        out_set(0, 0);
        out_set(1, v);
    }
}

void hbridge_freq(uint32_t hz) {
    uint8_t best = 0;
    uint32_t err = 0xFFFFFFFFUL;
    for (uint8_t i = 0; i < 5; i++) {
        uint32_t f = F_CPU / 256UL / prescale[i];
        uint32_t e = f > hz ? f - hz : hz - f;
        if (e < err) {
            err = e;
            best = i;
        }
    }
    TCCR0B = (uint8_t)(best + 1); /* CS0 = 1..5 */
}

void hbridge_init(uint8_t i, transducer_t *t, uint8_t out, pin_t dir, float ramp, uint8_t brake,
                  uint8_t invert, uint32_t freq) {
    hbridge_t *m = &motors[i & 1];
    m->t = t;
    m->out = out;
    m->dir = dir;
    m->ramp = ramp;
    m->brake = brake;
    m->invert = invert;
    OC0A_PORT &= (uint8_t)~_BV(OC0A_BIT);
    OC0B_PORT &= (uint8_t)~_BV(OC0B_BIT);
    if (out != 1) OC0A_DDR |= _BV(OC0A_BIT);
    if (out != 0) OC0B_DDR |= _BV(OC0B_BIT);
    if (out < 2) pin_output(&dir, 0);
    TCCR0A = (uint8_t)((TCCR0A & (_BV(COM0A1) | _BV(COM0B1))) | _BV(WGM01) | _BV(WGM00));
    hbridge_freq(freq);
    apply(m, 0.0f);
}

void hbridge_set(uint8_t i, float ramp, uint8_t brake, uint32_t freq) {
    hbridge_t *m = &motors[i & 1];
    m->ramp = ramp;
    m->brake = brake;
    hbridge_freq(freq);
    if (m->duty == 0.0f) apply(m, 0.0f); /* a new stop mode shows at once */
}

static void report(hbridge_t *m, uint32_t now) {
    uint32_t raw;
    __builtin_memcpy(&raw, &m->duty, 4);
    record(m->t, 0, raw, now);
}

static void step(hbridge_t *m, uint32_t now) { /* (last_us: the command's, or the step's before) */
    float dt = (float)(now - m->last_us) / 1e6f;
    m->last_us = now;
    float most = m->ramp * (dt > RAMP_STEP_US / 1e6f ? dt : RAMP_STEP_US / 1e6f);
    float delta = m->target - m->duty;
    if (delta <= most && delta >= -most) m->duty = m->target;
    else m->duty += delta > 0 ? most : -most;
    apply(m, m->duty);
    report(m, now);
    m->ramping = m->duty != m->target;
    m->due = now + RAMP_STEP_US;
}

uint8_t hbridge_command(uint8_t i, const uint8_t *in, uint8_t n, uint8_t *out, uint8_t *out_n) {
    hbridge_t *m = &motors[i & 1];
    (void)out;
    *out_n = 0;
    if (n != 4) return 0xFF;
    float d;
    __builtin_memcpy(&d, in, 4);
    if (!(d >= -1.0f && d <= 1.0f)) return 0xFF; /* (NaN too) */
    uint32_t now = clock_now();
    m->target = d;
    m->last_us = now;
    if (m->ramp <= 0) {
        m->duty = d;
        apply(m, d);
        report(m, now);
    } else {
        step(m, now);
    }
    return 0;
}

void hbridge_poll(uint8_t i, uint32_t now) {
    hbridge_t *m = &motors[i & 1];
    if (m->ramping && clock_due(now, m->due)) step(m, now);
}

void hbridge_make_safe(uint8_t i) {
    hbridge_t *m = &motors[i & 1];
    m->target = m->duty = 0.0f;
    m->ramping = 0;
    apply(m, 0.0f);
    report(m, clock_now());
}
