/* Voltages on the ADC inputs (analog.c): a Sharp GP2Y0A02YK's output for a distance, or any
 * voltage (a battery's divider).
 * Control lines:
 *   sharp MM: the Sharp's target at MM millimetres (its voltage from the datasheet's curve)
 *   ain CH MV: MV millivolts on ADC channel CH (0..15) */
#ifndef RIG_ANALOG_H
#define RIG_ANALOG_H
#include "rig.h"

void sharp_add(int channel); /* a Sharp on ADC channel `channel`, its target at 800 mm */
int ain_add(int channel, uint32_t mv); /* mv millivolts on it from the start (0: no channel) */
int analog_command(const char *line);
#endif
