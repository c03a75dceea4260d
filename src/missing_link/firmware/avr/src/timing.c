/* Acting on host time on AVR: the same functions, bytes and texts as board/timing.py (Python).
 *
 * Theory of operation
 * -------------------
 * The host's map of this board's clock (a2jHostMap: <Q board us><q host ns><i rate - 1, ppb>)
 * converts both ways in 64-bit integer maths (floor division, as Python's //); a map with a
 * rate off by more than 10 % or references beyond those sums is refused, the one before kept.
 * A map vouches for board times within MAP_LIFE_US of its reference.  a2jAt [q host ns][B function][payload]
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
static uint64_t map_b0;
static int64_t map_h0;
static int32_t map_ppb;
uint32_t timing_unaligned, timing_done, timing_refused, timing_cancelled;
uint8_t (*timing_hardware)(uint8_t fn, uint64_t tick, const uint8_t *payload, uint8_t n);
uint8_t (*timing_hardware_held)(uint8_t drop, int64_t after);

static struct {
    uint64_t tick;
    uint8_t fn, n, used;
    uint8_t payload[TIMED_PAYLOAD];
} queue[TIMED_QUEUE];

static uint64_t get_u64(const uint8_t *p) {
    uint64_t v = 0;
    for (int8_t i = 7; i >= 0; i--) v = (v << 8) | p[i];
    return v;
}

static void put_u64(uint8_t *p, uint64_t v) {
    for (uint8_t i = 0; i < 8; i++) p[i] = (uint8_t)(v >> (8 * i));
}

static int64_t floor_div(int64_t a, int64_t b) { /* b > 0 */
    int64_t q = a / b;
    return (a % b != 0 && a < 0) ? q - 1 : q;
}

static uint8_t say(uint8_t *out, const char *text);

uint8_t host_map_fn(const uint8_t *in, uint8_t n, uint8_t *out, uint8_t *out_n) {
    /* every field checked, as board/runtime.py: a map the host got wrong is refused (the one
     * before kept); a rate of -1e9 ppb divided by zero in timing_board_at */
    *out_n = 0;
    if (n == 20) {
        uint64_t b0 = get_u64(in);
        int64_t h0 = (int64_t)get_u64(in + 8);
        int32_t ppb = (int32_t)((uint32_t)in[16] | ((uint32_t)in[17] << 8) | ((uint32_t)in[18] << 16) |
                                ((uint32_t)in[19] << 24));
        if (ppb < -MAX_PPB || ppb > MAX_PPB) {
            *out_n = say(out, PSTR("rate off by more than 10 % (ppb)"));
            return 0xFF;
        }
        if (b0 > (uint64_t)INT64_MAX || h0 < -MAX_HOST_NS || h0 > MAX_HOST_NS) {
            *out_n = say(out, PSTR("board us beyond 2^63 or host ns beyond +-2^62"));
            return 0xFF;
        }
        map_b0 = b0;
        map_h0 = h0;
        map_ppb = ppb;
        host_map_set = 1;
        return 0;
    }
    if (n == 0 && host_map_set) {
        put_u64(out, map_b0);
        put_u64(out + 8, (uint64_t)map_h0);
        memcpy(out + 16, &map_ppb, 4);
        *out_n = 20;
        return 0;
    }
    if (n) *out_n = say(out, PSTR("expects <Q board us><q host ns><i ppb> or nothing"));
    return 0xFF;
}

uint8_t timing_map_valid(uint64_t now) {
    if (!host_map_set) return 0;
    int64_t d = (int64_t)(now - map_b0);
    return d >= -MAP_LIFE_US && d <= MAP_LIFE_US;
}

int64_t timing_host_at(uint64_t board_us) {
    return map_h0 + floor_div((int64_t)(board_us - map_b0) * (1000000000LL + map_ppb), 1000000LL);
}

int64_t timing_board_at(int64_t host_ns) {
    /* (host times further than FAR_NS from the map's are held there: no overflow, and such a
     * tick is refused anyway, as past or beyond the map's life) */
    int64_t d = host_ns > map_h0 + FAR_NS ? FAR_NS : host_ns < map_h0 - FAR_NS ? -FAR_NS : host_ns - map_h0;
    return (int64_t)map_b0 + floor_div(d * 1000000LL, 1000000000LL + map_ppb);
}

uint8_t timing_next_grid(uint32_t period_us, float phase, uint64_t now, uint64_t *tick) {
    if (!timing_map_valid(now)) return 0;
    int64_t p = (int64_t)period_us * 1000;
    int64_t off = (int64_t)(phase * (float)p) % p;
    int64_t h = timing_host_at(now);
    int64_t k = floor_div(h - off, p) + 1;
    *tick = (uint64_t)timing_board_at(k * p + off);
    return 1;
}

static uint8_t say(uint8_t *out, const char *text) {
    uint8_t k = 0;
    while (pgm_read_byte(text) && k < 250) out[k++] = pgm_read_byte(text++);
    return k;
}

static uint8_t utoa_at(uint8_t *out, uint8_t k, uint32_t v) {
    char d[11];
    uint8_t n = 0;
    do {
        d[n++] = (char)('0' + v % 10);
        v /= 10;
    } while (v);
    while (n) out[k++] = (uint8_t)d[--n];
    return k;
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

uint8_t timing_at(const uint8_t *in, uint8_t n, uint8_t *out, uint8_t *out_n) {
    *out_n = 0;
    if (n < 9) {
        *out_n = say(out, PSTR("expects [q host ns][B function index][payload]"));
        return 0xFF;
    }
    int64_t host_ns = (int64_t)get_u64(in);
    uint8_t fn = in[8];
    uint64_t now = board_clock();
    timing_refused++;
    function_t f;
    if (fn < board_function_count) function_get(fn, &f);
    if (fn >= board_function_count || !timeable(&f, fn)) {
        *out_n = say(out, PSTR("only an actuator's call or a2jGoodbye can be timed"));
        return 0xFF;
    }
    if (n - 9 > TIMED_PAYLOAD) { /* (AVR only: the queue's entries are small) */
        *out_n = say(out, PSTR("payload too long for a timed call (4 bytes)"));
        return 0xFF;
    }
    if (!timing_map_valid(now)) {
        *out_n = say(out, PSTR("no valid host map (a2jHostMap)"));
        return 0xFF;
    }
    int64_t at = timing_board_at(host_ns);
    if (at < (int64_t)now) {
        uint8_t k = say(out, PSTR("past by "));
        int64_t late = (int64_t)now - at;
        k = utoa_at(out, k, late > 0xFFFFFFFFLL ? 0xFFFFFFFFUL : (uint32_t)late);
        *out_n = (uint8_t)(k + say(out + k, PSTR(" us")));
        return 0xFF;
    }
    uint64_t tick = (uint64_t)at;
    if ((int64_t)(tick - map_b0) > MAP_LIFE_US) {
        uint8_t k = utoa_at(out, 0, (uint32_t)((tick - now) / 1000));
        k += say(out + k, PSTR(" ms ahead: beyond what the map vouches for ("));
        k = utoa_at(out, k, (uint32_t)(MAP_LIFE_US / 1000));
        *out_n = (uint8_t)(k + say(out + k, PSTR(" ms)")));
        return 0xFF;
    }
    if (!(timing_hardware && timing_hardware(fn, tick, in + 9, (uint8_t)(n - 9)))) {
        uint8_t slot = 0;
        while (slot < TIMED_QUEUE && queue[slot].used) slot++;
        if (slot == TIMED_QUEUE) {
            *out_n = say(out, PSTR("timed calls queue full"));
            return 0xFF;
        }
        queue[slot].tick = tick;
        queue[slot].fn = fn;
        queue[slot].n = (uint8_t)(n - 9);
        memcpy(queue[slot].payload, in + 9, n - 9);
        queue[slot].used = 1;
    }
    timing_refused--;
    put_u64(out, tick);
    *out_n = 8;
    return 0;
}

void timing_poll(uint64_t now) {
    uint8_t reply_n; /* (what the function answers goes nowhere: into the scratch buffer) */
    for (uint8_t i = 0; i < TIMED_QUEUE; i++) {
        if (queue[i].used && queue[i].tick <= now) {
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
    uint8_t n = timing_hardware_held ? timing_hardware_held(0, -1) : 0;
    for (uint8_t i = 0; i < TIMED_QUEUE; i++) n += queue[i].used;
    return n;
}

void timing_cancel(const char *why, uint32_t ms, int64_t after) {
    uint8_t n = timing_hardware_held ? timing_hardware_held(1, after) : 0;
    for (uint8_t i = 0; i < TIMED_QUEUE; i++) {
        if (queue[i].used && (int64_t)queue[i].tick > after) {
            queue[i].used = 0;
            n++;
        }
    }
    if (!n) return;
    timing_cancelled += n;
    log_line_P(LOG_WARN, LOG_BOARD, PSTR("timed calls dropped: "), why);
    uint8_t text[24];
    runtime_debug_P(PSTR("timing: "));
    text[utoa_at(text, 0, n)] = 0;
    runtime_debug((const char *)text);
    runtime_debug_P(n == 1 ? PSTR(" timed call dropped (") : PSTR(" timed calls dropped ("));
    runtime_debug_P(why);
    if (ms != 0xFFFFFFFFUL) {
        uint8_t k = say(text, PSTR(" for "));
        k = utoa_at(text, k, ms);
        text[k + say(text + k, PSTR(" ms"))] = 0;
        runtime_debug((const char *)text);
    }
    runtime_debug_P(PSTR(");"));
}

uint8_t timing_info(const uint8_t *in, uint8_t n, uint8_t *out, uint8_t *out_n) {
    (void)in;
    (void)n;
    uint64_t now = board_clock();
    uint32_t age = 0xFFFFFFFFUL;
    if (host_map_set) {
        int64_t d = (int64_t)(now - map_b0) / 1000;
        age = d < 0 ? 0 : d > 0xFFFFFFFELL ? 0xFFFFFFFEUL : (uint32_t)d;
    }
    uint32_t v[4] = {age, timing_unaligned, timing_done, timing_refused};
    out[0] = timing_map_valid(now);
    memcpy(out + 1, v, 16);
    *out_n = 17;
    return 0;
}
