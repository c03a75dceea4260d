/* A stepper driver (DRV8825, A4988) at the firmware's step, direction and enable pins
 * (stepper.c): each rising step edge while enabled (enable low) is a step, forward while the
 * direction pin is high; steps while disabled are counted apart.
 * Control line: stepper: "stepper POS ENABLED STEPS IGNORED" */
#ifndef RIG_STEPPER_H
#define RIG_STEPPER_H
#include "rig.h"

/* en_port 0: no enable pin (always enabled) */
void stepper_add(char step_port, int step_bit, char dir_port, int dir_bit, char en_port, int en_bit);
int stepper_command(const char *line);
#endif
