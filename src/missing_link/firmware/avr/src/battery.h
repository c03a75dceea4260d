/* A battery's voltage through a resistor divider on the ADC (battery.c;
 * board/drivers/battery.py). */
#ifndef J2A_BATTERY_H
#define J2A_BATTERY_H
#include <stdint.h>

#include "runtime.h"

#define BATTERY_MAX_READS 9

/* points: every chemistry's curve of (volts per cell, charge) pairs in flash, lowest first, one
 * after another in the Python driver's CHEMISTRIES order (linear last); starts[c]..starts[c + 1]:
 * chemistry c's pairs (board_gen.c makes both from the Python driver's CURVES). */
void battery_init(transducer_t *t, uint8_t adc_channel, float rate_hz, float vref, float ratio,
                  uint8_t cells, uint8_t chemistry, uint8_t reads, const float *points,
                  const uint8_t *starts);
void battery_set(float rate_hz, float ratio, uint8_t cells, uint8_t chemistry);
void battery_align(uint8_t aligned, float phase);
void battery_poll(uint32_t now);
#endif
