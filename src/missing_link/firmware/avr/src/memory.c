/* The stack's low point, seen from inside (docs/hardware.md, "Memory"), as board/memory.py says
 * the heap's on MicroPython.
 *
 * Theory of operation
 * -------------------
 * Before anything runs (.init1, straight after reset: no stack in use yet, so in assembly, with
 * no C conventions to rely on) every byte from the end of static RAM (_end: .data and .bss) to
 * the top of RAM is painted STACK_CANARY.  The stack grows down from the top; whatever it ever
 * reached is overwritten.  a2jMemory counts from _end up the bytes still painted: the stack has
 * never come that close to static RAM.  (No malloc here: nothing else writes there.  A stack
 * byte that happens to hold STACK_CANARY at the deepest point counts as untouched: the figure
 * may be a byte or two high, never low.)  rig_sim's "stack" finds the same low point from
 * outside, as the lowest stack pointer.
 *
 * a2jMemory -> [B 2][H bytes never touched][H stack room: top of RAM - _end]
 *              [H static RAM: _end - start of RAM][H RAM]  (a MicroPython board: [B 1], its heap)
 */
#include "memory.h"

#include <avr/io.h>

extern uint8_t _end;
extern uint8_t __stack;

void memory_paint(void) __attribute__((naked, used, section(".init1")));
void memory_paint(void) {
    __asm__ volatile(
        "    ldi r30, lo8(_end)\n"
        "    ldi r31, hi8(_end)\n"
        "    ldi r24, %0\n"
        "    ldi r25, hi8(__stack)\n"
        "    rjmp 2f\n"
        "1:  st Z+, r24\n"
        "2:  cpi r30, lo8(__stack)\n"
        "    cpc r31, r25\n"
        "    brlo 1b\n"
        "    breq 1b\n" ::"M"(STACK_CANARY));
}

uint16_t memory_stack_untouched(void) {
    const uint8_t *p = &_end;
    while (p <= &__stack && *p == STACK_CANARY) p++;
    return (uint16_t)(p - &_end);
}

static void put16(uint8_t *out, uint16_t v) {
    out[0] = (uint8_t)v;
    out[1] = (uint8_t)(v >> 8);
}

uint8_t memory_info(const uint8_t *in, uint8_t n, uint8_t *out, uint8_t *out_n) {
    (void)in;
    (void)n;
    out[0] = 2;
    put16(out + 1, memory_stack_untouched());
    put16(out + 3, (uint16_t)(&__stack - &_end + 1));
    put16(out + 5, (uint16_t)(&_end - (uint8_t *)RAMSTART));
    put16(out + 7, (uint16_t)(RAMEND + 1 - RAMSTART));
    *out_n = 9;
    return 0;
}
