/* The InvenSense MPU-6050 IMU on the TWI (mpu6050.c): the MicroPython driver's channels, units,
 * keys and faults (board/drivers/mpu6050.py). */
#ifndef J2A_MPU6050_H
#define J2A_MPU6050_H
#include <stdint.h>

#include "runtime.h"
#include "schedule.h"

typedef struct {
    transducer_t *t;
    schedule_t s;
    uint8_t addr;     /* 7 bit: 0x68, 0x69 with AD0 high */
    uint8_t afs, fs;  /* the ranges' indices: +-2 g << afs, +-250 deg/s << fs */
    uint8_t dlpf, ok; /* ok: set up with these (0: before the next sample) */
} mpu6050_t;

void mpu6050_init(mpu6050_t *m, transducer_t *t, uint8_t address, uint16_t rate_hz, uint8_t afs,
                  uint8_t fs, uint8_t dlpf);
void mpu6050_set(mpu6050_t *m, float rate_hz, uint8_t afs, uint8_t fs, uint8_t dlpf);
void mpu6050_align(mpu6050_t *m, uint8_t aligned, float phase);
void mpu6050_poll(mpu6050_t *m, uint32_t now);
extern uint16_t mpu6050_bus_errors; /* all of them: every failed set-up or sample */
#endif
