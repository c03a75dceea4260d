/* An InvenSense MPU-6050 on the rig's TWI bus (mpu6050.c), from its register map (RM-MPU-6000A
 * rev 4.2): WHO_AM_I, PWR_MGMT_1 (asleep after reset: its data registers read 0 until woken),
 * CONFIG, GYRO_CONFIG and ACCEL_CONFIG (the ranges scale its readings), and the 14 data
 * registers from ACCEL_XOUT_H (big-endian int16, clipped), the register pointer stepping on
 * through a burst.
 * Control lines (K: the IMU, in the order they were added; 0 when left out):
 *   imu [K] AX AY AZ GX GY GZ T: what it feels: m/s^2 (gravity included: at rest, level,
 *          0 0 9.80665), rad/s, degC (at power-up: at rest, level, 25 degC)
 *   imu_absent [K] 1/0: taken off the bus (it acknowledges nothing), or put back
 *   imu_regs [K]: "imu_regs K PWR CONFIG GYRO ACCEL", what the firmware set (hex) */
#ifndef RIG_MPU6050_H
#define RIG_MPU6050_H
#include "rig.h"

void mpu6050_add(uint8_t addr); /* at 7-bit address `addr` (0x68; 0x69 with AD0 high) */
/* what IMU k feels (the seam for a world: motor.c sets the yaw rate of a turning rover) */
void mpu6050_feel(int k, const double accel[3], const double gyro[3], double temp_c);
int mpu6050_command(const char *line);
#endif
