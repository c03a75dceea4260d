/* The J2A board runtime for AVR: requests in, replies and sample SIFs out.
 *
 * Theory of operation
 * -------------------
 * The main loop hands every received byte to runtime_feed() with the board time the UART's
 * interrupt stamped it at; the frame parser (wire.c) turns bytes into requests, and each complete
 * request is answered at once: the reply is encoded straight into the UART's TX ring (waiting
 * for room if a long reply needs it: the host is waiting for it anyway).  runtime_poll() lets the
 * drivers run, then writes each transducer with new values as one sample SIF, but only when the
 * TX ring has room for the SIF's worst case: a SIF never waits and never splits a reply.  A value
 * that arrives on a channel that still holds an unsent one flushes that SIF first; if the ring
 * is full then, that older SIF is dropped whole and counted (sifs_dropped), its seq taken so
 * the host counts it lost: the newest sample wins, a sample is never torn (the Python runtime's
 * queue drops its oldest SIF whole too), and every loss has a number.
 *
 * Function table order and every reply byte follow the Python runtime (board/runtime.py), so
 * the host cannot tell the two apart: a2jGetMapping, a2jMany, a2jGetProperties, a2jDebug,
 * a2jEcho, a2jEchoMany, then Part 2 (a2jGetMappingMany, a2jGetTransds, a2jClock, a2jHostMap,
 * a2jSifCount), then the board's own functions.  a2jClock's t2 is the interrupt's stamp of the
 * request's last byte, t3 is taken just before the reply's first byte enters the TX ring.
 * No dynamic allocation; the one 255-byte scratch buffer is shared by replies and SIFs.  The
 * board's log (log.c) writes its lines as SIFs of their own (runtime_sif_P, handed to it by
 * log_init: the log never calls the runtime by name), straight from flash: the scratch buffer
 * may hold a reply in the making when a driver says something.
 */
#include "builtins.h"

#include <avr/pgmspace.h>
#include <string.h>

#include "hal.h"
#include "log.h"
#include "wire.h"

static frame_parser_t parser;
static uint8_t scratch[255];
static uint32_t last_byte_us, request_us;
static char debug_text[64];
static uint8_t debug_len;
static uint8_t sif_seq;
uint32_t runtime_last_frame_us;
uint32_t sifs_dropped, sifs_sent, sif_total, calls;
char clock_epoch[9];

static void tx(uint8_t b) { link_write(b); }

uint8_t *runtime_scratch(void) { return scratch; }

void runtime_debug(const char *text) {
    while (*text && debug_len < sizeof debug_text) debug_text[debug_len++] = *text++;
}

void runtime_debug_P(const char *text) {
    char c;
    while ((c = (char)pgm_read_byte(text++)) && debug_len < sizeof debug_text)
        debug_text[debug_len++] = c;
}

uint8_t runtime_decimal(uint8_t *out, uint8_t at, uint32_t v) {
    uint8_t d[10], n = 0;
    do {
        d[n++] = (uint8_t)('0' + v % 10);
        v /= 10;
    } while (v);
    while (n) out[at++] = d[--n];
    return at;
}

void runtime_debug_why(const char *why, uint32_t ms) {
    runtime_debug_P(why);
    if (ms != 0xFFFFFFFFUL) {
        char text[11];
        text[runtime_decimal((uint8_t *)text, 0, ms)] = 0;
        runtime_debug_P(PSTR(" for "));
        runtime_debug(text);
        runtime_debug_P(PSTR(" ms"));
    }
    runtime_debug_P(PSTR(");"));
}

uint8_t runtime_say(uint8_t *out, uint8_t at, const char *text) {
    char c;
    while ((c = (char)pgm_read_byte(text++)) && at < 250) out[at++] = (uint8_t)c;
    return at;
}

static void reply(uint8_t seq, uint8_t code, const uint8_t *payload, uint8_t n) {
    encode_frame(tx, SOF, seq, code, payload, n);
}

static void error_frame(uint8_t seq, uint8_t code, uint16_t diag) {
    uint8_t d[2] = {(uint8_t)(diag >> 8), (uint8_t)diag};
    reply(seq, code, d, 2);
}

void function_get(uint8_t i, function_t *f) { memcpy_P(f, &board_functions[i], sizeof *f); }

/* The function at index i into *f; an index past the table is answered here (ERR_INDEX): 0 */
static uint8_t function_or_refuse(uint8_t seq, uint8_t i, function_t *f) {
    if (i >= board_function_count) {
        error_frame(seq, ERR_INDEX, DIAG_INDEX);
        return 0;
    }
    function_get(i, f);
    return 1;
}

/* ---- blobs -------------------------------------------------------------------------------- */
static const char *function_name(uint8_t i) {
    return (const char *)pgm_read_ptr(&board_functions[i].name);
}

static uint16_t mapping_len(void) {
    uint16_t n = 0;
    for (uint8_t i = 0; i < board_function_count; i++) n += strlen_P(function_name(i)) + 1;
    return n;
}

static uint8_t mapping_at(uint16_t k) {
    for (uint8_t i = 0; i < board_function_count; i++) {
        const char *name = function_name(i);
        uint16_t len = strlen_P(name) + 1;
        if (k < len) return k + 1 == len ? 0 : pgm_read_byte(name + k);
        k -= len;
    }
    return 0;
}

const blob_t mapping_blob = {mapping_len, mapping_at};

uint8_t get_mapping(const uint8_t *in, uint8_t n, uint8_t *out, uint8_t *out_n) {
    /* As much as fits in one reply, cut at a name boundary (the full table: GetMappingMany).
     * A request with a payload (spec 1.6: len 0) is this board's own reply of 0 heard back:
     * answering it with another 0 would echo for ever (and feed the failsafe): 0xFF. */
    (void)in;
    *out_n = 0;
    if (n) return 0xFF;
    uint16_t total = mapping_len(), cut = 0;
    for (uint16_t k = 0; k < total && k < 255; k++) {
        out[k] = mapping_at(k);
        if (out[k] == 0) cut = k + 1;
    }
    *out_n = (uint8_t)(total <= 255 ? total : cut);
    return 0;
}

/* ---- built-in plain functions -------------------------------------------------------------- */
uint8_t get_debug(const uint8_t *in, uint8_t n, uint8_t *out, uint8_t *out_n) {
    (void)in;
    (void)n;
    memcpy(out, debug_text, debug_len);
    *out_n = debug_len;
    debug_len = 0;
    return 0;
}

uint8_t echo(const uint8_t *in, uint8_t n, uint8_t *out, uint8_t *out_n) {
    memmove(out, in, n);
    *out_n = n;
    return 0xBA;
}

uint8_t sif_count(const uint8_t *in, uint8_t n, uint8_t *out, uint8_t *out_n) {
    (void)in;
    (void)n;
    memset(out + 4, 0, 4); /* (a Q: the count's high word) */
    memcpy(out, &sif_total, 4);
    *out_n = 8;
    return 0;
}

static uint8_t not_plain(const uint8_t *in, uint8_t n, uint8_t *out, uint8_t *out_n) {
    (void)in;
    (void)n;
    (void)out;
    *out_n = 0;
    return 0xFF;
}

const char n_get_mapping[] PROGMEM = "a2jGetMapping";
const char n_many[] PROGMEM = "a2jMany";
const char n_get_properties[] PROGMEM = "a2jGetProperties";
const char n_debug[] PROGMEM = "a2jDebug";
const char n_echo[] PROGMEM = "a2jEcho";
const char n_echo_many[] PROGMEM = "a2jEchoMany";
const char n_get_mapping_many[] PROGMEM = "a2jGetMappingMany";
const char n_get_transds[] PROGMEM = "a2jGetTransds";
const char n_clock[] PROGMEM = "a2jClock";
const char n_host_map[] PROGMEM = "a2jHostMap";
const char n_sif_count[] PROGMEM = "a2jSifCount";

/* ---- a2jMany (spec 1.11) -------------------------------------------------------------------- */
static void many(uint8_t seq, const uint8_t *in, uint8_t n) {
    if (n < 6) { /* as the original: 0xFF, the request payload echoed */
        memmove(scratch, in, n);
        reply(seq, 0xFF, scratch, n);
        return;
    }
    uint8_t target = in[0], flags = in[1];
    uint32_t offset = (uint32_t)in[2] | ((uint32_t)in[3] << 8) | ((uint32_t)in[4] << 16) |
                      ((uint32_t)in[5] << 24);
    function_t fn;
    if (!function_or_refuse(seq, target, &fn)) return;
    const function_t *f = &fn;
    uint8_t ret = 0xFF, last = 1, len = 0;
    uint8_t *data = scratch + 6;
    if (f->kind == KIND_BLOB) {
        if (flags & 2) { /* write to a read-only blob: flags byte 00, as the original */
            last = 0;
        } else {
            uint16_t total = f->blob->len();
            ret = 0;
            while (offset + len < total && len < MANY_CHUNK) {
                data[len] = f->blob->at((uint16_t)(offset + len));
                len++;
            }
            last = offset + len >= total;
        }
    } else if (f->kind == KIND_ECHO_MANY) {
        len = n - 6;
        if (len > MANY_CHUNK) len = MANY_CHUNK;
        memmove(data, in + 6, len);
        ret = 0xBE;
        last = flags & 1;
    }
    memmove(scratch + 2, in + 2, 4); /* the offset, echoed */
    scratch[0] = ret;
    scratch[1] = last ? 1 : 0;
    reply(seq, 0, scratch, (uint8_t)(6 + len));
}

/* ---- requests ------------------------------------------------------------------------------- */
/* (out of line: runtime_feed, run for every byte, stays light) */
static __attribute__((noinline)) void dispatch(uint8_t seq, uint8_t op, const uint8_t *in,
                                               uint8_t n) {
    calls++;
    function_t fn_op;
    if (!function_or_refuse(seq, op, &fn_op)) return;
    const function_t *f = &fn_op;
    if (op == 1) {
        many(seq, in, n);
        return;
    }
    if (f->kind == KIND_CLOCK && n == 0) {
        /* t2: the stamp of the request's last byte; t3: now, as the reply enters the ring */
        uint64_t t[2] = {clock_widen(request_us), 0};
        t[1] = board_clock();
        memcpy(scratch, t, 16);
        reply(seq, 0, scratch, 16);
        return;
    }
    plain_fn_t fn = f->kind == KIND_PLAIN ? f->plain : not_plain;
    uint8_t out_n = 0;
    uint8_t code = fn(in, n, scratch, &out_n);
    if (code >= 0xF0 && code <= 0xF4) {
        runtime_debug("reserved code;");
        log_fault_P(LOG_BOARD, FAULT_BAD_REPLY, 0);
        code = 0xFF;
    }
    reply(seq, code, scratch, out_n);
}

void runtime_feed(uint8_t b, uint32_t rx_us) {
    last_byte_us = rx_us;
    uint8_t ev = frame_parser_feed(&parser, b);
    if (ev == EV_NONE) return;
    if (ev == EV_REQUEST) {
        if (parser.op >= ERR_INDEX && parser.op <= ERR_ESCAPE) {
            /* an error code is never a function's index: an error frame of this board's heard
             * back (RS-485 hearing itself, a tty echoing): not the host, and not answered */
            log_fault_P(LOG_BOARD, FAULT_ECHOED, 0);
            return;
        }
        /* a request for a function of the table: the host is there (failsafe.c) */
        if (parser.op < board_function_count) runtime_last_frame_us = rx_us;
        request_us = rx_us;
        dispatch(parser.seq, parser.op, parser.buf, parser.n);
    } else if (parser.has_seq) {
        if (ev == EV_CUT) error_frame(parser.seq, ERR_TIMEOUT, DIAG_CUT);
        else if (ev == EV_CHECKSUM) error_frame(parser.seq, ERR_CHECKSUM, DIAG_CHECKSUM);
        else error_frame(parser.seq, ERR_ESCAPE, DIAG_ESCAPE);
    }
}

/* ---- samples -------------------------------------------------------------------------------- */
static uint8_t sif_payload(transducer_t *t, uint64_t now) {
    /* [t0 v0 t1 v1 ...]; channels without a new value carry N/A, stamped now; each stamp widened
     * to 64 bits against now (hal.h) */
    uint8_t k = 0;
    for (uint8_t ch = 0; ch < t->chan_count; ch++) {
        uint16_t has = t->pending & (1u << ch);
        uint64_t stamp = has ? now + (int64_t)(int32_t)(t->stamps[ch] - (uint32_t)now) : now;
        memcpy(scratch + k, &stamp, 8);
        k += 8;
        uint32_t v = has ? t->values[ch] : t->na;
        for (uint8_t i = 0; i < t->size; i++) scratch[k++] = (uint8_t)(v >> (8 * i));
    }
    t->pending = 0;
    return k;
}

#ifdef J2A_PROFILE
#include <avr/io.h>
volatile uint32_t prof_sif_ticks, prof_sifs; /* see main.c */
#endif

/* Write t's SIF if the ring has room for its worst case; 0 if it had to wait. */
static uint8_t flush_sif(transducer_t *t, uint64_t now) {
    uint8_t n = (uint8_t)(t->chan_count * (8 + t->size));
    if (link_tx_free() < FRAME_MAX(n)) return 0;
#ifdef J2A_PROFILE
    uint16_t t0 = TCNT1;
#endif
    n = sif_payload(t, now);
    encode_frame(tx, SOS, sif_seq++, t->tid, scratch, n);
    sif_total++;
    sifs_sent++;
#ifdef J2A_PROFILE
    uint16_t t1 = TCNT1;
    prof_sif_ticks += t1 >= t0 ? t1 - t0 : (uint16_t)(t1 + 40000u - t0);
    prof_sifs++;
#endif
    return 1;
}

/* A SIF whose payload is head[0..hn) then the flash strings a, b (0: none), written whole into
 * the UART's ring if it has room; 1 if it was, 0 if not (nothing written): the log's send. */
static uint8_t runtime_sif_P(uint8_t cmd, const uint8_t *head, uint8_t hn, const char *a, const char *b) {
    uint8_t an = a ? (uint8_t)strlen_P(a) : 0, bn = b ? (uint8_t)strlen_P(b) : 0;
    if (link_tx_free() < FRAME_MAX((uint16_t)hn + an + bn)) return 0;
    encode_frame_P(tx, SOS, sif_seq++, cmd, head, hn, a, an, b, bn);
    sif_total++;
    sifs_sent++;
    return 1;
}

/* A value on a channel that holds an unsent one: that SIF goes first, or, with no room for it,
 * is dropped whole.  Dropping the one channel tore a sample: the next channel's flush could find
 * room (the UART drained a byte meanwhile) and send the new value beside the older ones, the
 * rest following with N/A where the new ones had been sent (an MPU-6050 burst as two SIFs). */
static void keep(transducer_t *t, uint8_t ch, uint32_t raw, uint32_t stamp) {
    if (t->pending & (1u << ch)) {
        if (!flush_sif(t, clock_widen(stamp))) { /* no room: the older SIF goes, counted */
            sifs_dropped++;
            t->pending = 0;
            sif_seq++; /* (its seq with it, as the Python runtime's queue drops: the host */
            sif_total++; /* sees the gap and counts it lost; a2jSifCount counts it too) */
        }
    }
    t->stamps[ch] = stamp;
    t->values[ch] = raw;
    t->pending |= (uint16_t)(1u << ch);
}

void record(transducer_t *t, uint8_t channel, uint32_t raw, uint32_t stamp_us) {
    if (channel >= t->chan_count || !t->enabled) return;
    keep(t, channel, raw, stamp_us);
}

void record_na(transducer_t *t, uint8_t channel, uint32_t stamp_us) {
    if (channel >= t->chan_count || !t->enabled) return;
    keep(t, channel, t->na, stamp_us);
}

void runtime_poll(void) {
    uint64_t wide = board_clock(); /* (the SIFs' N/A stamps, and what the others widen against) */
    uint32_t now = (uint32_t)wide;
    board_poll(now);
    for (uint8_t i = 0; i < board_transducer_count; i++) {
        if (board_transducers[i].pending) flush_sif(&board_transducers[i], wide);
    }
    log_poll(now); /* a count of dropped log lines, when the budget has room (log.c) */
    if (frame_parser_in_frame(&parser) && now - last_byte_us > INTERBYTE_TIMEOUT_US) {
        if (frame_parser_abort(&parser) == EV_CUT && parser.has_seq)
            error_frame(parser.seq, ERR_TIMEOUT, DIAG_SILENCE);
    }
}

void runtime_init(void) {
    frame_parser_init(&parser);
    log_init(runtime_sif_P); /* the log writes its lines as SIFs of their own, through us */
}
