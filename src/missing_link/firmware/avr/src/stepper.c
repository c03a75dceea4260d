/* A stepper through a step/dir driver: the same keys, command and trapezoid as
 * board/drivers/stepper.py (Python), which says what the driver chips want.  Steps are timed
 * from the main loop (each at its µs), so the loop's latency is the step timing's jitter: a few
 * kHz at most, as on MicroPython.  The step pulse is high for 2 µs (the DRV8825's 1.9 µs). */
#include "stepper.h"

#include <math.h>
#include <stdlib.h>
#include <util/delay.h>

#include "hal.h"

#define REPORT_US 50000UL
enum { GOTO, SPEED, STOP };

static transducer_t *st;
static pin_t step_pin, dir_pin, en_pin;
static uint8_t has_en, invert, velocity_mode, mode = STOP;
static uint16_t per_rev;
static float max_speed, accel, speed, goal; /* steps/s, steps/s^2, steps/s, steps or steps/s */
static int32_t position;
static uint32_t next_us, last_step, reported; /* board µs (hal.h) */
static uint8_t moving, stepped, said; /* next_us, last_step and reported hold one */

void stepper_init(transducer_t *t, pin_t step, pin_t dir, pin_t enable, uint8_t has_enable,
                  uint16_t steps_per_rev, float max_rev_s, float accel_rev_s2, uint8_t velocity,
                  uint8_t inv) {
    st = t;
    step_pin = step;
    dir_pin = dir;
    en_pin = enable;
    has_en = has_enable;
    per_rev = steps_per_rev;
    invert = inv;
    stepper_set(max_rev_s, accel_rev_s2, velocity);
    pin_output(&step_pin, 0);
    pin_output(&dir_pin, 0);
    if (has_en) pin_output(&en_pin, 1); /* off (active low) until moved */
}

void stepper_set(float max_rev_s, float accel_rev_s2, uint8_t velocity) {
    max_speed = max_rev_s;
    accel = accel_rev_s2;
    velocity_mode = velocity;
}

static void enable(uint8_t on) {
    if (has_en) pin_set(&en_pin, !on);
}

static void put(uint8_t ch, float v, uint32_t now) {
    uint32_t raw;
    __builtin_memcpy(&raw, &v, 4);
    record(st, ch, raw, now);
}

static void report(uint32_t now) {
    reported = now;
    said = 1;
    put(0, (float)position / per_rev, now);
    put(1, speed / per_rev, now);
}

static uint8_t wants_motion(void) {
    if (mode == GOTO) return lroundf(goal) != position || speed != 0;
    if (mode == SPEED) return goal != 0 || speed != 0;
    return speed != 0;
}

uint8_t stepper_command(const uint8_t *in, uint8_t n, uint8_t *out, uint8_t *out_n) {
    (void)out;
    *out_n = 0;
    if (n != 4) return 0xFF;
    float v;
    __builtin_memcpy(&v, in, 4);
    if (v != v) { /* N/A: let go */
        stepper_make_safe();
        return 0;
    }
    /* too far: beyond 1e6 rev, or its steps beyond an int32 (the infinities too), as in
     * stepper.py; lroundf of such a goal is undefined */
    if (!(fabsf(v) <= 1e6f) || fabsf(v) * per_rev >= 2147483648.0f) return 0xFF;
    if (velocity_mode && fabsf(v) > max_speed) return 0xFF;
    uint32_t now = clock_now();
    mode = velocity_mode ? SPEED : GOTO;
    goal = v * per_rev;
    if (mode == GOTO || v != 0) enable(1);
    if (!moving && wants_motion()) {
        moving = 1;
        next_us = now;
    }
    report(now);
    return 0;
}

static float target_speed(void) {
    float vmax = max_speed * per_rev, a = accel * per_rev;
    if (mode == SPEED) return goal;
    if (mode == STOP) return 0;
    int32_t togo = lroundf(goal) - position;
    if (togo == 0) return 0;
    float braking = speed * speed / (2 * a);
    if (speed != 0 && labs(togo) <= braking + 1 && (togo > 0) == (speed > 0)) return 0; /* slow down */
    return togo > 0 ? vmax : -vmax;
}

void stepper_poll(uint32_t now) {
    if (!st || !moving || !clock_due(now, next_us)) return;
    float a = accel * per_rev, v0 = sqrtf(2 * a);
    float dt = stepped ? (float)(now - last_step) / 1e6f : 0;
    float want = target_speed(), v = speed;
    if (v == 0) {
        v = want > 0 ? v0 : want < 0 ? -v0 : 0;
    } else {
        float dv = a * (dt > 1 / fabsf(v) ? dt : 1 / fabsf(v));
        if (want > v) v = v + dv < want ? v + dv : want;
        else if (want < v) v = v - dv > want ? v - dv : want;
        if (v != 0 && (v > 0) != (speed > 0)) v = 0; /* through zero: stop first */
        else if (want == 0 && fabsf(v) < v0) { /* slower than a step from rest: stop, or go on */
            int32_t left = mode == GOTO ? lroundf(goal) - position : 0;
            v = left && (left > 0) == (v > 0) ? (v > 0 ? v0 : -v0) : 0;
        }
    }
    int32_t togo = mode == GOTO ? lroundf(goal) - position : 1;
    if (v == 0 || (mode == GOTO && togo == 0 && fabsf(v) <= v0 * 1.5f)) {
        speed = 0;
        moving = stepped = 0;
        if (togo != 0 && wants_motion()) { /* (turning round) */
            moving = 1;
            next_us = now;
        }
        report(now);
        return;
    }
    speed = v;
    uint8_t forward = v > 0;
    pin_set(&dir_pin, forward != invert);
    pin_set(&step_pin, 1);
    _delay_us(2);
    pin_set(&step_pin, 0);
    position += forward ? 1 : -1;
    last_step = now;
    stepped = 1;
    next_us = now + (uint32_t)(1e6f / fabsf(v));
    if (!said || now - reported >= REPORT_US) report(now);
}

void stepper_make_safe(void) {
    mode = STOP;
    speed = 0;
    moving = stepped = 0;
    enable(0);
    report(clock_now());
}
