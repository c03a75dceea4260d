/* What the rig's parts share (rig.h): the simulated AVR, its time and its pins.  rig_sim.c
 * loads the AVR, runs the parts and reads their control lines; the parts call only this. */
#include "rig.h"

#include <string.h>

#include "avr_ioport.h"

avr_t *avr;

uint64_t sim_us(void) { return avr->cycle / (avr->frequency / 1000000); }

void rig_pin(char port, int bit, int level) {
    avr_raise_irq(avr_io_getirq(avr, AVR_IOCTL_IOPORT_GETIRQ(port), bit), level);
}

avr_irq_t *rig_pin_irq(char port, int bit) {
    return avr_io_getirq(avr, AVR_IOCTL_IOPORT_GETIRQ(port), bit);
}

int rig_port_bit(char port, int bit) {
    for (avr_io_t *io = avr->io_port; io; io = io->next) {
        avr_ioport_t *p = (avr_ioport_t *)io;
        if (!strcmp(io->kind, "port") && p->name == port) return (avr->data[p->r_port] >> bit) & 1;
    }
    return 0;
}

int rig_parse_pin(const char *text, char *port, int *bit) {
    if ((text[0] == 'P' || text[0] == 'p') && text[1] >= 'A') text++;
    char p = (char)(text[0] & ~0x20);
    if (p < 'A' || p > 'L' || text[1] < '0' || text[1] > '7' || text[2]) return 0;
    *port = p;
    *bit = text[1] - '0';
    return 1;
}
