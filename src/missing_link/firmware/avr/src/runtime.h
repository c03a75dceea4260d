/* The J2A board runtime in C: the same concepts and names as the Python runtime
 * (board/runtime.py): a function table, properties, transducers, feed / poll / output. */
#ifndef J2A_RUNTIME_H
#define J2A_RUNTIME_H
#include <stdint.h>

#define J2A_VERSION "2"
#define ERR_INDEX 0xF0
#define ERR_TIMEOUT 0xF2
#define ERR_CHECKSUM 0xF3
#define ERR_ESCAPE 0xF4
#define MANY_CHUNK 249
#define INTERBYTE_TIMEOUT_US 10000UL
#define DIAG_CUT 1
#define DIAG_SILENCE 2
#define DIAG_CHECKSUM 3
#define DIAG_ESCAPE 4
#define DIAG_INDEX 5

/* A plain function: payload in, return code out, reply in out[0..*out_n). */
typedef uint8_t (*plain_fn_t)(const uint8_t *in, uint8_t n, uint8_t *out, uint8_t *out_n);
/* A read-only blob served through a2jMany: its length and its byte at i. */
typedef struct {
    uint16_t (*len)(void);
    uint8_t (*at)(uint16_t i);
} blob_t;

enum { KIND_PLAIN = 0, KIND_BLOB, KIND_ECHO_MANY, KIND_CLOCK };

typedef struct {
    const char *name; /* in flash (PROGMEM) */
    uint8_t kind;
    plain_fn_t plain;
    const blob_t *blob;
} function_t;

/* Data types (spec 2.2), as board/dtypes.py */
enum { DT_INT8 = 0, DT_UINT8, DT_INT16, DT_UINT16, DT_INT32, DT_UINT32, DT_FLOAT };

typedef struct {
    uint8_t tid;
    uint8_t dtype;
    uint8_t chan_count; /* at most 16 on AVR (pending) */
    uint8_t size;       /* bytes per value */
    uint32_t na;        /* N/A value, raw little-endian bits */
    volatile uint16_t pending; /* bit per channel with an unsent value */
    uint32_t *stamps;   /* chan_count stamps (board µs, low 32 bits: hal.h) */
    uint32_t *values;   /* chan_count raw values */
    uint16_t values_dropped;
    uint8_t enabled;    /* run-time configuration (config.c): off = not polled, no SIFs */
} transducer_t;

/* Board tables, generated from the board file (board_gen.c) */
extern const function_t board_functions[]; /* in flash (PROGMEM): read with function_get */
void function_get(uint8_t i, function_t *f);
extern const uint8_t board_function_count;
extern transducer_t board_transducers[];
extern const uint8_t board_transducer_count;
void board_setup(void);              /* drivers and their pins */
void board_poll(uint32_t now);       /* drivers that need CPU time (now: hal.h) */

void runtime_init(void);
void runtime_feed(uint8_t b, uint32_t rx_us);
void runtime_poll(void);
/* Drivers: a value (raw bits of the transducer's type) or N/A, stamped at stamp_us (board µs,
 * low 32 bits: widened when its SIF is written, hal.h). */
void record(transducer_t *t, uint8_t channel, uint32_t raw, uint32_t stamp_us);
void record_na(transducer_t *t, uint8_t channel, uint32_t stamp_us);
/* The 255-byte buffer replies are made in: a timed call's reply, which goes nowhere (timing.c),
 * is made there too, between two turns of the main loop. */
uint8_t *runtime_scratch(void);
void runtime_debug(const char *text);
void runtime_debug_P(const char *text); /* from flash */
/* a2jDebug's tail of a note (failsafe.c, timing.c): why (in flash), " for MS ms" unless ms is
 * 0xFFFFFFFF, ");" */
void runtime_debug_why(const char *why, uint32_t ms);
/* text (in flash) at out[at..] (up to 250 bytes in all): the index after it */
uint8_t runtime_say(uint8_t *out, uint8_t at, const char *text);
/* v in decimal at out[at..]: the index after it */
uint8_t runtime_decimal(uint8_t *out, uint8_t at, uint32_t v);
extern uint32_t runtime_last_frame_us;  /* when the last intact frame came (failsafe.c) */

extern uint32_t sifs_dropped, sifs_sent, sif_total, calls;
extern char clock_epoch[9];
#endif
