/* The rover's parts around the firmware in simavr (rover.c), for rig_sim on a Mega 2560 with
 * examples/boards/rover-mega.py's wiring. */
#ifndef RIG_ROVER_H
#define RIG_ROVER_H
#include "sim_avr.h"

void rover_init(avr_t *avr);
int rover_command(const char *cmd); /* 1: it was one of ours (answered on stdout) */
double rig_board_us(avr_cycle_count_t cycle); /* rig_sim.c: a cycle in the board's µs */
#endif
