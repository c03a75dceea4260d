/* The MPU-6050 (mpu6050.h): board/drivers/mpu6050.py says what the datasheet asks (the
 * registers, the one 14-byte burst per sample, the scaling); the comments here say only what
 * differs on this hardware: the scaling in float (the AVR's 32 bits) and the faults said without
 * a text but for another part's identity (log.c). */
#include "mpu6050.h"

#include <avr/pgmspace.h>

#include "hal.h"
#include "log.h"
#include "twi.h"

#define G 9.80665f
#define DEG 0.017453292519943295f
#define WRONG_PART 0x80 /* (beside twi.h's TWI_NO_ANSWER and TWI_BUS) */
uint16_t mpu6050_bus_errors;

void mpu6050_init(mpu6050_t *m, transducer_t *t, uint8_t address, uint16_t rate_hz, uint8_t afs,
                  uint8_t fs, uint8_t dlpf) {
    m->t = t;
    m->addr = address;
    m->s.period_us = 1000000UL / rate_hz;
    m->afs = afs;
    m->fs = fs;
    m->dlpf = dlpf;
    twi_init();
}

void mpu6050_set(mpu6050_t *m, float rate_hz, uint8_t afs, uint8_t fs, uint8_t dlpf) {
    sched_rate(&m->s, rate_hz);
    if (afs != m->afs || fs != m->fs || dlpf != m->dlpf) m->ok = 0; /* before the next sample */
    m->afs = afs;
    m->fs = fs;
    m->dlpf = dlpf;
}

void mpu6050_align(mpu6050_t *m, uint8_t aligned, float phase) {
    sched_align(&m->s, aligned, phase);
}

static uint8_t put(const mpu6050_t *m, uint8_t reg, uint8_t v) {
    return twi_transfer(m->addr, reg, &v, 1, 0, 0);
}

/* WHO_AM_I, then awake on the X gyro's PLL, the filter and the ranges: 0, a TWI status, or
 * WRONG_PART */
static uint8_t start(mpu6050_t *m) {
    uint8_t who = 0, st = twi_transfer(m->addr, 0x75, 0, 0, &who, 1);
    if (st) return st;
    if (who != 0x68) return WRONG_PART;
    if ((st = put(m, 0x6B, 0x01)) || (st = put(m, 0x1A, m->dlpf)) ||
        (st = put(m, 0x1B, (uint8_t)(m->fs << 3))) || (st = put(m, 0x1C, (uint8_t)(m->afs << 3))))
        return st;
    m->ok = 1;
    return 0;
}

static void put_float(transducer_t *t, uint8_t ch, float v, uint32_t stamp) {
    uint32_t raw;
    __builtin_memcpy(&raw, &v, 4);
    record(t, ch, raw, stamp);
}

void mpu6050_poll(mpu6050_t *m, uint32_t now) {
    if (!sched_due(&m->s, &now)) return;
    sched_wait(&m->s, &now);
    uint8_t starting = !m->ok, st = starting ? start(m) : 0, r[14];
    uint32_t stamp = clock_now();
    if (!st) st = twi_transfer(m->addr, 0x3B, 0, 0, r, 14); /* ax ay az temp gx gy gz */
    if (st) { /* said once a kind (log.c), counted; the chip set up again before the next */
        static const char wrong[] PROGMEM = "WHO_AM_I is not 0x68: not an MPU-6050";
        if (st == WRONG_PART) log_fault_P(m->t->tid, FAULT_WRONG_ID, wrong);
        else log_fault_P(m->t->tid, starting ? FAULT_NO_ANSWER : FAULT_BUS, 0);
        mpu6050_bus_errors++;
        m->ok = 0;
        for (uint8_t ch = 0; ch < 7; ch++) record_na(m->t, ch, now);
        return;
    }
    float k = G / (float)(16384 >> m->afs), w = DEG / (131.0f / (float)(1 << m->fs));
    for (uint8_t ch = 0; ch < 7; ch++) {
        float v = (float)(int16_t)((r[2 * ch] << 8) | r[2 * ch + 1]);
        put_float(m->t, ch, ch < 3 ? v * k : ch == 3 ? v / 340.0f + 36.53f : v * w, stamp);
    }
}
