/* The TWI (I2C) master on AVR (twi.c), shared by the bus drivers (srf02.c, mpu6050.c). */
#ifndef J2A_TWI_H
#define J2A_TWI_H
#include <stdint.h>

enum { TWI_OK = 0, TWI_NO_ANSWER = 1, TWI_BUS = 2 };

void twi_init(void); /* 100 kHz master */
/* To the part at 7-bit `addr`: write reg and w[0..wn), then (rn > 0) read r[0..rn); TWI_OK, or
 * TWI_NO_ANSWER (no acknowledge: absent or busy) or TWI_BUS (a bus error), the bus released. */
uint8_t twi_transfer(uint8_t addr, uint8_t reg, const uint8_t *w, uint8_t wn, uint8_t *r,
                     uint8_t rn);
#endif
