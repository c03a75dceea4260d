/* The board's memory figures (a2jMemory): its stack's low point, painted at boot (memory.c). */
#ifndef J2A_MEMORY_H
#define J2A_MEMORY_H
#include <stdint.h>

#define STACK_CANARY 0xC5

uint16_t memory_stack_untouched(void);
uint8_t memory_info(const uint8_t *in, uint8_t n, uint8_t *out, uint8_t *out_n); /* a2jMemory */
#endif
