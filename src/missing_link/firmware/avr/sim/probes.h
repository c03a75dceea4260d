/* What the rig measures at the firmware's pins and registers (probes.c): the board's clock, the
 * servo's frame and pulse on OC1A, the trigger's edges on OC2A, ADC0's conversions and the
 * lowest the stack has been.
 * Control lines:
 *   pulse: "pulse US period US frames N", the servo's pulse width (from the timer's registers),
 *          the frame period measured at the pin and the frames seen
 *   trig:  "trig EDGES RISE_US FALL_US", the trigger pin's edges (OC2A: Uno D11 / Mega D10),
 *          the last ones in the board's µs
 *   adc:   "adc N T1 T2 ...": the starts of the last conversions of ADC0, in the board's µs
 *   stack: "stack MIN_SP PC": the lowest the stack pointer has been, and where (a byte address)
 *   irqoff: "irqoff V:CYCLES ... main:CYCLES", the longest stretch with interrupts off since last
 *          asked (measured from the first time it is asked), by where it began: interrupt routine V
 *          (its vector number) or the main loop */
#ifndef RIG_PROBES_H
#define RIG_PROBES_H
#include "rig.h"

void probes_init(const char *mcu);
void probes_watch(void); /* after every instruction */
int probes_command(const char *line);
#endif
