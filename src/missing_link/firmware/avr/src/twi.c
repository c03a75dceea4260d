/* The TWI (I2C) master the bus drivers share (twi.h): 100 kHz, every wait bounded, so a stuck
 * or absent part is an error returned, never a hang. */
#include "twi.h"

#include <avr/io.h>
#include <util/twi.h>

void twi_init(void) {
    TWSR = 0;
    TWBR = 72; /* 100 kHz at 16 MHz */
}

static uint8_t twi_wait(void) {
    for (uint16_t i = 0; i < 2000; i++) /* ~ 1 ms at 16 MHz: a stuck bus is an error, not a hang */
        if (TWCR & _BV(TWINT)) return 1;
    return 0;
}

static uint8_t twi_cmd(uint8_t cr) {
    TWCR = (uint8_t)(cr | _BV(TWINT) | _BV(TWEN));
    return twi_wait() ? TW_STATUS : 0xFF;
}

/* A step whose status must differ from the one before it (an address after a start; a read's
 * first byte and its last: 0x40 -> 0x50 ... 0x50 -> 0x58).  On a real TWI the new status is
 * there when TWINT is; simavr 1.6 can show TWINT a moment before it, so wait for both.  The
 * bytes between (0x50 after 0x50) wait for TWINT alone: their status does not change. */
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

uint8_t twi_transfer(uint8_t addr, uint8_t reg, const uint8_t *w, uint8_t wn, uint8_t *r, uint8_t rn) {
    uint8_t st = twi_cmd(_BV(TWSTA));
    if (st != TW_START && st != TW_REP_START) goto bus;
    TWDR = (uint8_t)(addr << 1);
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
        TWDR = (uint8_t)((addr << 1) | 1);
        st = twi_cmd_change(0);
        if (st == TW_MR_SLA_NACK) {
            twi_stop();
            return 1;
        }
        if (st != TW_MR_SLA_ACK) goto bus;
        for (uint8_t i = 0; i < rn; i++) {
            uint8_t last = i + 1 == rn, cr = last ? 0 : _BV(TWEA);
            st = i == 0 || last ? twi_cmd_change(cr) : twi_cmd(cr);
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

