/* The TWI (I2C) bus of the rig (twi_bus.c): the devices on it, each at its 7-bit address, as
 * simavr's TWI master talks to them (one message per start, byte and stop). */
#ifndef RIG_TWI_BUS_H
#define RIG_TWI_BUS_H
#include "rig.h"

typedef struct twi_device {
    uint8_t addr; /* 7 bit */
    /* a start with this address (read: 1 for a read): 1 acknowledges it (the device answers) */
    int (*start)(struct twi_device *d, int read);
    void (*write)(struct twi_device *d, uint8_t b); /* a byte the master wrote (acknowledged) */
    uint8_t (*read)(struct twi_device *d);          /* the byte the master reads next */
    struct twi_device *next;
} twi_device_t;

void twi_bus_init(void);
void twi_bus_add(twi_device_t *d);
/* messages seen on the bus, and the last one (simavr's avr_twi_msg_irq_t) */
void twi_bus_stats(unsigned *msgs, uint32_t *last);
#endif
