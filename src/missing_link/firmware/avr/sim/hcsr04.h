/* An HC-SR04 at the firmware's trigger and echo pins (hcsr04.c): at the trigger pulse's falling
 * edge the echo rises 450 µs later (the burst) for the round trip at 343.4 m/s (20 degC), or
 * for 38 ms with nothing in range.
 * Control line: hcsr04 MM: its target at MM millimetres (0: nothing in range) */
#ifndef RIG_HCSR04_H
#define RIG_HCSR04_H
#include "rig.h"

void hcsr04_add(char trig_port, int trig_bit, char echo_port, int echo_bit);
int hcsr04_command(const char *line);
#endif
