/* Acting on host time on AVR: the same functions, bytes and texts as board/timing.py (Python).
 *
 * Theory of operation
 * -------------------
 * The host's map of this board's clock (a2jHostMap: <Q board us><q host ns><i rate - 1, ppb>)
 * converts both ways in 64-bit integer maths (floor division, as Python's //); a map with a
 * rate off by more than 10 % or references beyond those sums is refused, the one before kept.
 * A map vouches for board times within MAP_LIFE_US of its reference, so a tick it gives is
 * kept in the firmware's 32-bit time (hal.h) and said in 64 bits.  a2jAt [q host ns][B function][payload]
 * calls a function at the tick the host time maps to (reply: 0 + [Q tick]) or refuses: no valid
 * map, past, beyond what the map vouches for, queue full, or not timeable.  Only an actuator's
 * command or a2jGoodbye can be timed (timeable(): as board/timing.py); a2jAt of a2jAt, of
 * a2jMany (no handler: a call through address 0) or of a reader is refused when asked.  A
 * timed call runs with the whole 255-byte scratch buffer for its reply (which goes nowhere):
 * the contract of every plain function.  One its function refuses when due is counted as
 * refused, not done, and said in the log (WARN).  A call
 * the hardware can make on its own at the tick (the trigger: Timer2's compare A, trigger.c)
 * is handed to it; every other one runs from the main loop when due (its latency: the loop's).
 * A call not yet carried out is dropped, counted, when the host is gone (timing_cancel, from
 * failsafe.c: all on a2jGoodbye; those due after the moment the host had been silent for the
 * shortest failsafe_ms).
 * a2jAlignInfo: [B map valid][I map age ms][I unaligned samples][I done][I refused].
 */
#include "timing.h"

#include <avr/pgmspace.h>
#include <string.h>

#include "failsafe.h"
#include "hal.h"
#include "log.h"
#include "runtime.h"

#define FAR_NS 100000000000LL /* 100 s */
#define MAX_PPB 100000000L     /* a host map's rate: within 10 % of 1 (board/runtime.py) */
#define MAX_HOST_NS (1LL << 62)

static uint8_t host_map_set;
static struct { /* as a2jHostMap carries it (an AVR is little-endian and packs structs) */
    uint64_t b0;
    int64_t h0;
    int32_t ppb;
} map;
uint32_t timing_unaligned, timing_done, timing_refused, timing_cancelled;
uint8_t (*timing_hardware)(uint8_t fn, uint32_t tick, const uint8_t *payload, uint8_t n);
uint8_t (*timing_hardware_held)(uint8_t drop, uint8_t all, uint32_t after);

static struct {
    uint32_t tick; /* board µs, low 32 bits */
    uint8_t fn, n, used;
    uint8_t payload[TIMED_PAYLOAD];
} queue[TIMED_QUEUE];

static __attribute__((noinline)) int64_t floor_div(int64_t a, int64_t b) { /* b > 0 */
    int64_t q = a / b;
    return (a % b != 0 && a < 0) ? q - 1 : q;
}

#define say(out, text) runtime_say(out, 0, text)

uint8_t host_map_fn(const uint8_t *in, uint8_t n, uint8_t *out, uint8_t *out_n) {
    /* every field checked, as board/runtime.py: a map the host got wrong is refused (the one
     * before kept); a rate of -1e9 ppb divided by zero in board_at */
    const char *why = PSTR("expects <Q board us><q host ns><i ppb> or nothing");
    *out_n = 0;
    if (n == 20) {
        int64_t h0;
        int32_t ppb;
        memcpy(&h0, in + 8, 8);
        memcpy(&ppb, in + 16, 4);
        if (ppb < -MAX_PPB || ppb > MAX_PPB) {
            why = PSTR("rate off by more than 10 % (ppb)");
        } else if ((in[7] & 0x80) || h0 < -MAX_HOST_NS || h0 > MAX_HOST_NS) {
            why = PSTR("board us beyond 2^63 or host ns beyond +-2^62");
        } else {
            memcpy(&map, in, 20);
            host_map_set = 1;
            return 0;
        }
    } else if (n == 0 && host_map_set) {
        memcpy(out, &map, 20);
        *out_n = 20;
        return 0;
    } else if (n == 0) {
        return 0xFF;
    }
    *out_n = say(out, why);
    return 0xFF;
}

static __attribute__((noinline)) uint8_t map_valid(uint64_t now) {
    if (!host_map_set) return 0;
    return now - map.b0 + MAP_LIFE_US <= 2 * MAP_LIFE_US; /* within +-MAP_LIFE_US */
}

static __attribute__((noinline)) int64_t board_at(int64_t host_ns) {
    /* (host times further than FAR_NS from the map's are held there: no overflow, and such a
     * tick is refused anyway, as past or beyond the map's life) */
    int64_t d = host_ns > map.h0 + FAR_NS   ? FAR_NS
                : host_ns < map.h0 - FAR_NS ? -FAR_NS
                                            : host_ns - map.h0; /* (no overflow: |h0| <= 2^62) */
    return (int64_t)map.b0 + floor_div(d * 1000000LL, 1000000000LL + map.ppb);
}

uint8_t timing_next_grid(uint32_t period_us, float phase, uint32_t now, uint32_t *tick) {
    uint64_t wide = clock_widen(now);
    if (!map_valid(wide)) return 0;
    int64_t p = (int64_t)period_us * 1000;
    int64_t off = (int64_t)(phase * (float)p) % p;
    /* the host time at now (a valid map: now within MAP_LIFE_US of its reference, 32 bits) */
    int32_t d = (int32_t)(now - (uint32_t)map.b0);
    int64_t h = map.h0 + floor_div((int64_t)d * (1000000000L + map.ppb), 1000000LL);
    int64_t k = floor_div(h - off, p) + 1;
    *tick = (uint32_t)board_at(k * p + off);
    return 1;
}

/* An actuator's command (a board file's call=: avrgen.py puts only those in the table under
 * names that are not a2j + a capital, which boardfile.py keeps for the firmware's own) or
 * a2jGoodbye; f is function fn of the table. */
static uint8_t timeable(const function_t *f, uint8_t fn) {
    if (f->kind != KIND_PLAIN || !f->plain) return 0;
    if (f->plain == failsafe_goodbye) return 1;
    const char *name = (const char *)pgm_read_ptr(&board_functions[fn].name);
    char c = (char)pgm_read_byte(name + 3);
    return !(pgm_read_byte(name) == 'a' && pgm_read_byte(name + 1) == '2' &&
             pgm_read_byte(name + 2) == 'j' && c >= 'A' && c <= 'Z');
}

/* where a2jAt puts a call due at `tick`: the hardware, or the queue (0: full) */
static __attribute__((noinline)) uint8_t enqueue(uint8_t fn, uint32_t tick, const uint8_t *payload, uint8_t n) {
    if (timing_hardware && timing_hardware(fn, tick, payload, n)) return 1;
    for (uint8_t slot = 0; slot < TIMED_QUEUE; slot++) {
        if (!queue[slot].used) {
            queue[slot].tick = tick;
            queue[slot].fn = fn;
            queue[slot].n = n;
            memcpy(queue[slot].payload, payload, n);
            queue[slot].used = 1;
            return 1;
        }
    }
    return 0;
}

uint8_t timing_at(const uint8_t *in, uint8_t n, uint8_t *out, uint8_t *out_n) {
    const char *why = PSTR("expects [q host ns][B function index][payload]");
    uint8_t k = 0;
    function_t f;
    if (n < 9) goto refuse;
    int64_t host_ns;
    memcpy(&host_ns, in, 8);
    uint8_t fn = in[8];
    uint64_t now = board_clock();
    timing_refused++;
    if (fn < board_function_count) function_get(fn, &f);
    why = PSTR("only an actuator's call or a2jGoodbye can be timed");
    if (fn >= board_function_count || !timeable(&f, fn)) goto refuse;
    why = PSTR("payload too long for a timed call (4 bytes)"); /* (AVR only: small entries) */
    if (n - 9 > TIMED_PAYLOAD) goto refuse;
    why = PSTR("no valid host map (a2jHostMap)");
    if (!map_valid(now)) goto refuse;
    int64_t at = board_at(host_ns), ahead = at - (int64_t)now;
    if (ahead < 0) {
        uint64_t late = (uint64_t)-ahead;
        k = runtime_decimal(out, say(out, PSTR("past by ")), late >> 32 ? 0xFFFFFFFFUL : (uint32_t)late);
        why = PSTR(" us");
        goto refuse;
    }
    if (at - (int64_t)map.b0 > MAP_LIFE_US) { /* (ahead < 2^32: at is within FAR_NS of now) */
        k = runtime_decimal(out, 0, (uint32_t)ahead / 1000);
        k = runtime_say(out, k, PSTR(" ms ahead: beyond what the map vouches for ("));
        k = runtime_decimal(out, k, (uint32_t)(MAP_LIFE_US / 1000));
        why = PSTR(" ms)");
        goto refuse;
    }
    why = PSTR("timed calls queue full");
    if (!enqueue(fn, (uint32_t)at, in + 9, (uint8_t)(n - 9))) goto refuse;
    timing_refused--;
    memcpy(out, &at, 8);
    *out_n = 8;
    return 0;
refuse:
    *out_n = runtime_say(out, k, why);
    return 0xFF;
}

void timing_poll(uint32_t now) {
    uint8_t reply_n; /* (what the function answers goes nowhere: into the scratch buffer) */
    for (uint8_t i = 0; i < TIMED_QUEUE; i++) {
        if (queue[i].used && clock_due(now, queue[i].tick)) {
            queue[i].used = 0; /* (first: a timed a2jGoodbye empties the queue on its way) */
            function_t f;
            function_get(queue[i].fn, &f);
            if (f.plain(queue[i].payload, queue[i].n, runtime_scratch(), &reply_n) == 0) {
                timing_done++;
            } else { /* refused when due (disabled meanwhile, a value it does not take) */
                timing_refused++;
                log_line_P(LOG_WARN, LOG_BOARD, PSTR("a timed call refused when due: "),
                           (const char *)pgm_read_ptr(&board_functions[queue[i].fn].name));
            }
        }
    }
}

uint8_t timing_pending(void) {
    uint8_t n = timing_hardware_held ? timing_hardware_held(0, 1, 0) : 0;
    for (uint8_t i = 0; i < TIMED_QUEUE; i++) n += queue[i].used;
    return n;
}

void timing_cancel(const char *why, uint32_t ms, uint8_t all, uint32_t after) {
    uint8_t n = timing_hardware_held ? timing_hardware_held(1, all, after) : 0;
    for (uint8_t i = 0; i < TIMED_QUEUE; i++) {
        if (queue[i].used && (all || (int32_t)(queue[i].tick - after) > 0)) {
            queue[i].used = 0;
            n++;
        }
    }
    if (!n) return;
    timing_cancelled += n;
    log_line_P(LOG_WARN, LOG_BOARD, PSTR("timed calls dropped: "), why);
    char text[4];
    text[runtime_decimal((uint8_t *)text, 0, n)] = 0;
    runtime_debug_P(PSTR("timing: "));
    runtime_debug(text);
    runtime_debug_P(n == 1 ? PSTR(" timed call dropped (") : PSTR(" timed calls dropped ("));
    runtime_debug_why(why, ms);
}

uint8_t timing_info(const uint8_t *in, uint8_t n, uint8_t *out, uint8_t *out_n) {
    (void)in;
    (void)n;
    uint64_t now = board_clock();
    uint32_t age = 0xFFFFFFFFUL;
    if (host_map_set) {
        int64_t d = (int64_t)(now - map.b0);
        uint64_t ms = d < 0 ? 0 : (uint64_t)d / 1000;
        age = ms > 0xFFFFFFFEULL ? 0xFFFFFFFEUL : (uint32_t)ms;
    }
    uint32_t v[4] = {age, timing_unaligned, timing_done, timing_refused};
    out[0] = map_valid(now);
    memcpy(out + 1, v, 16);
    *out_n = 17;
    return 0;
}
