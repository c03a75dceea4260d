/* The SRF02 sonar on the rig's TWI bus (srf02.c), from its datasheet: its registers, no
 * acknowledge at all while it ranges (65 ms), the address-change sequence.
 * Control lines:
 *   srf02 CM: its target at CM centimetres
 *   echo 0/1: an echo comes back (1) or not (0: it ranges 0)
 *   srf02_absent 1/0: taken off the bus (it acknowledges nothing), or put back */
#ifndef RIG_SRF02_H
#define RIG_SRF02_H
#include "rig.h"

void srf02_add(uint8_t addr); /* at 7-bit address `addr` (0x70 at power-up) */
int srf02_command(const char *line);
/* rangings started, and its address now (the firmware may change it) */
void srf02_stats(unsigned *rangings, uint8_t *addr);
#endif
