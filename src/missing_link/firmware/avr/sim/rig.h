/* What the rig's parts share (rig.c; rig_sim.c runs them): the simulated AVR, its time, its pins, and
 * the shape of a part's control lines.
 *
 * The seam for a world around the rig (a physics model driving the parts: issue 47): every
 * part's state is set through its control lines on rig_sim's stdin (one line in, one line out),
 * and each part says in its header which lines it takes.  A world that computes the state
 * itself (where the wheels are, what the IMU feels) sets it there, and turns the rig's own
 * models off where it has one of its own (motor.c: `wheel K off`); its ticks go in a
 * `tick` line, a batch of them, each made at its simulated time (world.c). */
#ifndef RIG_RIG_H
#define RIG_RIG_H
#include <stdint.h>

#include "sim_avr.h"

extern avr_t *avr;

/* simulated µs since the AVR started */
uint64_t sim_us(void);
/* a cycle in the board's µs: its clock is Timer1 at 2 MHz, counted from the cycle the firmware
 * started it (probes.c); -1 before that */
double board_us_at(avr_cycle_count_t cycle);
/* drive an input pin of port `port` ('A'..'L') to level (0/1) */
void rig_pin(char port, int bit, int level);
/* the level the firmware writes to a pin (its PORT bit: an output's level) */
int rig_port_bit(char port, int bit);
/* a pin's IRQ (simavr's: what the firmware drives on it, for a part to watch) */
avr_irq_t *rig_pin_irq(char port, int bit);
/* "D2", "PD2" or "d2" -> port 'D', bit 2; 0 if it is not a pin */
int rig_parse_pin(const char *text, char *port, int *bit);

/* A part's control lines: 1 when the line was the part's (its answer printed on stdout), 0 when
 * not. */
typedef int (*rig_command_t)(const char *line);
#endif
