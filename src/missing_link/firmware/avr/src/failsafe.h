/* The failsafe on AVR: the same keys, functions and texts as board/failsafe.py (Python). */
#ifndef J2A_FAILSAFE_H
#define J2A_FAILSAFE_H
#include <stdint.h>

typedef struct {
    uint8_t k;               /* the transducer's index in board_transducers[] */
    const char *name;        /* its name (in flash), for the debug text */
    void (*make_safe)(void); /* its driver's: to its safe state, and report it */
} failsafe_entry_t;

/* board_gen.c hands its actuators (in flash) and their failsafe_ms (set by config.c) */
void failsafe_init(const failsafe_entry_t *table, uint16_t *ms, uint8_t count);
void failsafe_arm(uint8_t k); /* transducer k took a command (board_gen.c's call functions) */
void failsafe_poll(uint32_t now);
uint8_t failsafe_goodbye(const uint8_t *in, uint8_t n, uint8_t *out, uint8_t *out_n);
uint8_t failsafe_info(const uint8_t *in, uint8_t n, uint8_t *out, uint8_t *out_n);
#endif
