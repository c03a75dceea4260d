/* An MPU-6050 on the rig's TWI bus (mpu6050.h). */
#include "mpu6050.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "twi_bus.h"

#define IMUS 2
#define G 9.80665
#define PI 3.14159265358979323846

static struct imu {
    twi_device_t dev;
    uint8_t regs[128];
    uint8_t index, reg; /* bytes written since the start; the register pointer */
    int absent;
    double accel[3], gyro[3], temp_c; /* m/s^2, rad/s, degC */
} imus[IMUS];
static int n_imus;

static int16_t clip(double v) { return (int16_t)(v > 32767 ? 32767 : v < -32768 ? -32768 : lround(v)); }

/* the data registers from what it feels, scaled by the ranges set (asleep: as they were) */
static void sample(struct imu *m) {
    if (m->regs[0x6B] & 0x40) return; /* SLEEP */
    double lsb_g = 16384 >> ((m->regs[0x1C] >> 3) & 3);          /* LSB per g */
    double lsb_dps = 131.0 / (1 << ((m->regs[0x1B] >> 3) & 3)); /* LSB per deg/s */
    int16_t v[7];
    for (int i = 0; i < 3; i++) {
        v[i] = clip(m->accel[i] / G * lsb_g);
        v[4 + i] = clip(m->gyro[i] * 180 / PI * lsb_dps);
    }
    v[3] = clip((m->temp_c - 36.53) * 340);
    for (int i = 0; i < 7; i++) {
        m->regs[0x3B + 2 * i] = (uint8_t)((uint16_t)v[i] >> 8);
        m->regs[0x3C + 2 * i] = (uint8_t)v[i];
    }
}

static int start(twi_device_t *d, int read) {
    struct imu *m = (struct imu *)d;
    m->index = 0;
    if (read) sample(m); /* (a burst reads one instant: taken as it starts) */
    return !m->absent;
}

static void write(twi_device_t *d, uint8_t b) {
    struct imu *m = (struct imu *)d;
    if (m->index++ == 0) {
        m->reg = b & 0x7F;
        return;
    }
    if (m->reg == 0x6B && (b & 0x80)) { /* DEVICE_RESET: the registers as at power-up */
        memset(m->regs, 0, sizeof m->regs);
        m->regs[0x6B] = 0x40;
        m->regs[0x75] = 0x68;
    } else if (m->reg != 0x75 && (m->reg < 0x3B || m->reg > 0x48)) { /* (read-only ones kept) */
        m->regs[m->reg] = b;
    }
    m->reg = (m->reg + 1) & 0x7F;
}

static uint8_t read(twi_device_t *d) {
    struct imu *m = (struct imu *)d;
    uint8_t b = m->regs[m->reg];
    m->reg = (m->reg + 1) & 0x7F;
    return b;
}

void mpu6050_feel(int k, const double accel[3], const double gyro[3], double temp_c) {
    if (k < 0 || k >= n_imus) return;
    memcpy(imus[k].accel, accel, sizeof imus[k].accel);
    memcpy(imus[k].gyro, gyro, sizeof imus[k].gyro);
    imus[k].temp_c = temp_c;
}

void mpu6050_add(uint8_t addr) {
    if (n_imus == IMUS) return;
    struct imu *m = &imus[n_imus++];
    m->dev = (twi_device_t){.addr = addr, .start = start, .write = write, .read = read};
    m->regs[0x6B] = 0x40; /* asleep */
    m->regs[0x75] = 0x68; /* WHO_AM_I, whatever AD0 is */
    m->accel[2] = G;
    m->temp_c = 25.0;
    twi_bus_add(&m->dev);
}

/* "NAME [K] ...": K (0 when the line has `want` numbers only), and where the numbers start */
static int which(const char *cmd, const char *name, int want, const char **rest) {
    size_t n = strlen(name);
    if (strncmp(cmd, name, n) != 0 || (cmd[n] != ' ' && cmd[n] != 0)) return -1;
    const char *p = cmd + n;
    double x;
    int count = 0, used;
    for (const char *q = p; sscanf(q, "%lf%n", &x, &used) == 1; q += used) count++;
    int k = 0;
    if (count == want + 1) {
        k = (int)strtol(p, (char **)&p, 10);
    } else if (count != want) {
        return -1;
    }
    *rest = p;
    return k >= 0 && k < n_imus ? k : -1;
}

int mpu6050_command(const char *cmd) {
    const char *rest;
    int k, v;
    double a[3], g[3], t;
    if ((k = which(cmd, "imu", 7, &rest)) >= 0 &&
        sscanf(rest, "%lf %lf %lf %lf %lf %lf %lf", &a[0], &a[1], &a[2], &g[0], &g[1], &g[2], &t) == 7) {
        mpu6050_feel(k, a, g, t);
        printf("ok\n");
    } else if ((k = which(cmd, "imu_absent", 1, &rest)) >= 0 && sscanf(rest, "%d", &v) == 1) {
        imus[k].absent = v;
        printf("ok\n");
    } else if ((k = which(cmd, "imu_regs", 0, &rest)) >= 0) {
        uint8_t *r = imus[k].regs;
        printf("imu_regs %d %02x %02x %02x %02x\n", k, r[0x6B], r[0x1A], r[0x1B], r[0x1C]);
    } else {
        return 0;
    }
    return 1;
}
