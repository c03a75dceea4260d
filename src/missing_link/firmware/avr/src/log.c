/* The board's log on AVR (log.h; the theory of operation is board/log.py's, and the bytes are
 * the same).  What differs: the budget runs on the low 32 bits of the board clock (log_poll,
 * every loop turn, keeps it within a turn of now, so the wrap never shows), the counters are
 * 16 bit and stop at their top, and the fault table has LOG_FAULTS entries.  A line is written
 * into the UART's ring at once, stamped then, or dropped and counted when the budget or the
 * ring has no room for it. */
#include "log.h"

#include <avr/pgmspace.h>
#include <string.h>

#include "hal.h"

#define BURST 8
#define INTERVAL_US 250000UL
#if RAMEND > 0x900
#define LOG_FAULTS 8
#else
#define LOG_FAULTS 4 /* the Uno: 2 KiB of RAM */
#endif

static uint32_t tat; /* the budget's theoretical arrival time (board µs, low 32 bits) */
static uint16_t said, dropped, pending, other;
static uint8_t n_faults;
static log_send_t send; /* (set by runtime_init before any line: log_init) */
static struct {
    uint8_t source, kind;
    uint16_t count;
} faults[LOG_FAULTS];

static void add16(uint16_t *v) {
    if (*v != 0xFFFF) (*v)++;
}

/* One line if the budget and the ring have room; 0 (dropped, counted) if not. */
static uint8_t emit(uint64_t now, uint8_t level, uint8_t source, uint8_t kind, const char *a,
                    const char *b) {
    uint32_t t = (uint32_t)now;
    if ((int32_t)(t - (tat - (BURST - 1) * INTERVAL_US)) < 0) return 0;
    uint8_t head[13]; /* [Q board µs][B level][B source][B kind][H dropped] (AVR: little-endian) */
    memcpy(head, &now, 8);
    head[8] = level;
    head[9] = source;
    head[10] = kind;
    memcpy(head + 11, &pending, 2);
    if (!send(LOG_CMD, head, sizeof head, a, b)) return 0;
    tat = ((int32_t)(tat - t) > 0 ? tat : t) + INTERVAL_US;
    pending = 0;
    add16(&said);
    return 1;
}

void log_line_P(uint8_t level, uint8_t source, const char *text_P, const char *more_P) {
    if (!emit(board_clock(), level, source, FAULT_LINE, text_P, more_P)) {
        add16(&dropped);
        add16(&pending);
    }
}

void log_fault_P(uint8_t source, uint8_t kind, const char *text_P) {
    for (uint8_t i = 0; i < n_faults; i++) {
        if (faults[i].source == source && faults[i].kind == kind) {
            add16(&faults[i].count);
            return;
        }
    }
    if (n_faults == LOG_FAULTS) {
        add16(&other);
        return;
    }
    faults[n_faults].source = source;
    faults[n_faults].kind = kind;
    faults[n_faults++].count = 1;
    uint8_t level = kind == FAULT_BAD_REPLY ? LOG_ERROR : LOG_WARN;
    if (!emit(board_clock(), level, source, kind, text_P, 0)) {
        add16(&dropped);
        add16(&pending);
    }
}

void log_poll(uint32_t now) {
    uint32_t t = (uint32_t)now;
    if ((int32_t)(tat - t) < 0) tat = t; /* (idle: within a turn of now, whatever the wrap) */
    if (pending) emit(clock_widen(now), LOG_WARN, LOG_BOARD, FAULT_LINE, 0, 0);
}

void log_init(log_send_t s) { send = s; }

static uint8_t put32(uint8_t *out, uint16_t v) {
    uint32_t w = v;
    memcpy(out, &w, 4);
    return 4;
}

uint8_t log_info(const uint8_t *in, uint8_t n, uint8_t *out, uint8_t *out_n) {
    (void)in;
    (void)n;
    uint8_t k = put32(out, said);
    k += put32(out + k, dropped);
    k += put32(out + k, other);
    out[k++] = n_faults;
    for (uint8_t i = 0; i < n_faults; i++) {
        out[k++] = faults[i].source;
        out[k++] = faults[i].kind;
        k += put32(out + k, faults[i].count);
    }
    *out_n = k;
    return 0;
}
