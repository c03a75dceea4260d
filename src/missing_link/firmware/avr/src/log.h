/* The board's log on AVR: the same SIF, levels, fault kinds, budget and fault table as the
 * Python runtime's board/log.py, which says how they work (docs/board-log.md).  Texts live in
 * flash (PSTR) and go straight into the UART's ring: the log keeps no line in RAM. */
#ifndef J2A_LOG_H
#define J2A_LOG_H
#include <stdint.h>

#include "features.h"

#define LOG_CMD 0xFE   /* the SIF cmd: not a transducer id (0..239), not an error (0xF0..0xF4) */
#define LOG_BOARD 0xFF /* a line about the board itself, not one of its transducers */
enum { LOG_DEBUG = 10, LOG_INFO = 20, LOG_WARN = 30, LOG_ERROR = 40 };
enum {
    FAULT_LINE = 0,
    FAULT_NO_ANSWER,
    FAULT_WRONG_ID,
    FAULT_BUS,
    FAULT_TIMEOUT,
    FAULT_CHECKSUM,
    FAULT_OVERRUN,
    FAULT_RAISED_CALL,
    FAULT_RAISED_POLL,
    FAULT_RAISED_TIMED,
    FAULT_RAISED_SAFE,
    FAULT_STORAGE,
    FAULT_BAD_REPLY,
    FAULT_ECHOED /* a request whose opcode is an error code: an error frame heard back */
};

/* How a line leaves: the runtime's SIF writer (runtime_sif_P), handed over at start as the
 * Python runtime hands BoardLog its send; 1 if the UART's ring took the frame. */
typedef uint8_t (*log_send_t)(uint8_t cmd, const uint8_t *head, uint8_t hn, const char *a,
                              const char *b);

#if ML_LOG
void log_init(log_send_t send);
/* A line: text_P (and then more_P, either may be 0) from flash, if the budget allows. */
void log_line_P(uint8_t level, uint8_t source, const char *text_P, const char *more_P);
/* A fault: said once per (source, kind) - WARN, ERROR for a reply J2A cannot carry - then
 * counted; text_P (may be 0: the host names the kind) from flash. */
void log_fault_P(uint8_t source, uint8_t kind, const char *text_P);
void log_poll(uint32_t now); /* a count of dropped lines, once the budget has room */
uint8_t log_info(const uint8_t *in, uint8_t n, uint8_t *out, uint8_t *out_n); /* a2jLogInfo */
#else /* no log: the drivers' counters are all there is */
static inline void log_init(log_send_t send) { (void)send; }
static inline void log_line_P(uint8_t l, uint8_t s, const char *t, const char *m) {
    (void)l, (void)s, (void)t, (void)m;
}
static inline void log_fault_P(uint8_t s, uint8_t k, const char *t) { (void)s, (void)k, (void)t; }
static inline void log_poll(uint32_t now) { (void)now; }
#endif
#endif
