/* The TWI bus of the rig (twi_bus.h).  simavr 1.6's master raises a message on its output for
 * each start (with the address and R/W bit), each byte written or asked for, and each stop; the
 * device it addresses answers on the master's input at once: an acknowledge of the address or
 * of a byte written, or the byte read.  A device that does not acknowledge its address (absent,
 * busy) is not selected, and the master sees a NACK. */
#include "twi_bus.h"

#include <stddef.h>

#include "avr_twi.h"

static twi_device_t *devices, *selected;
static avr_irq_t *to_avr;
static unsigned msgs;
static uint32_t last_msg;

static void hook(struct avr_irq_t *irq, uint32_t value, void *param) {
    (void)irq;
    (void)param;
    avr_twi_msg_irq_t v;
    v.u.v = value;
    msgs++;
    last_msg = value;
    if (v.u.twi.msg & TWI_COND_STOP) selected = NULL;
    if (v.u.twi.msg & TWI_COND_START) {
        selected = NULL;
        for (twi_device_t *d = devices; d; d = d->next) {
            if ((v.u.twi.addr >> 1) == d->addr && d->start(d, v.u.twi.addr & 1)) {
                selected = d;
                avr_raise_irq(to_avr, avr_twi_irq_msg(TWI_COND_ACK, v.u.twi.addr, 1));
                break;
            }
        }
    }
    if (!selected) return;
    if (v.u.twi.msg & TWI_COND_WRITE) {
        avr_raise_irq(to_avr, avr_twi_irq_msg(TWI_COND_ACK, (uint8_t)(selected->addr << 1), 1));
        selected->write(selected, v.u.twi.data);
    }
    if (v.u.twi.msg & TWI_COND_READ)
        avr_raise_irq(to_avr, avr_twi_irq_msg(TWI_COND_READ, (uint8_t)(selected->addr << 1 | 1),
                                              selected->read(selected)));
}

void twi_bus_init(void) {
    static const char *names[] = {"8<twi_bus.in"};
    avr_irq_t *irq = avr_alloc_irq(&avr->irq_pool, 0, 1, names);
    avr_irq_register_notify(irq, hook, NULL);
    avr_connect_irq(avr_io_getirq(avr, AVR_IOCTL_TWI_GETIRQ(0), TWI_IRQ_OUTPUT), irq);
    to_avr = avr_io_getirq(avr, AVR_IOCTL_TWI_GETIRQ(0), TWI_IRQ_INPUT);
}

void twi_bus_add(twi_device_t *d) {
    d->next = devices;
    devices = d;
}

void twi_bus_stats(unsigned *n, uint32_t *last) {
    *n = msgs;
    *last = last_msg;
}
