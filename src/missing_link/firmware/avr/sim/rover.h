/* The rover's parts around the firmware in simavr (rover.c), for rig_sim on a Mega 2560 with
 * examples/boards/rover-mega.py's wiring. */
#ifndef RIG_ROVER_H
#define RIG_ROVER_H
#include "sim_avr.h"

/* board_us: a cycle in the board's µs (rig_sim.c's clock, handed in) */
void rover_init(avr_t *avr, double (*board_us)(avr_cycle_count_t cycle));
int rover_command(const char *cmd); /* 1: it was one of ours (answered on stdout) */
#endif
