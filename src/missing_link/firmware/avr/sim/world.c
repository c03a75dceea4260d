/* The world's batches of ticks: a world beside the rig (virtual/world_avr.py) computes the next
 * ticks at once, on the assumption that the drives hold, and hands them to the rig in one line;
 * the rig makes each at its own simulated time while the drives read as the world assumed, and
 * answers (one line) at the first where they do not, or at the batch's end.  So the world is
 * woken once a batch, not once a tick, and the parts get each tick's readings at its time.
 *
 *   tick ASKS|T0 FEED;FEED...|T1 FEED;...|...|TN
 *
 * ASKS: the lines whose answers (';' between) say the drives (`motor`, `stepper`); the rig's
 * last answer to them is the batch's assumption.  Each "T FEEDS" is a tick at simulated µs T and
 * the lines that put its readings into the parts (a ranger's target, the IMU's, an encoder's
 * edges: their headers); the last entry, a time alone, is where the world wants to be asked
 * next (the batch's end).  The first tick is made at once (the world ticked it on the drives
 * the rig answered).  Each later one is made when the simulated time reaches its T (the rig
 * looks every 1024 instructions; a line that came late: at once, each tick its own): its FEEDS
 * go into the parts if the asks' answers are still the assumption; else, and at the last
 * entry, the rig answers
 *
 *   tick SIM_US MADE ASKS'ANSWERS|ERRORS FIRST_ERROR
 *
 * SIM_US the simulated time then, MADE how many of the batch's ticks were made (the world goes
 * back to the first that was not and asks again from SIM_US: worldlink.py's ahead), the asks'
 * answers then (the next batch's assumption), and how many of the feeds' answers since the
 * last answer were errors, the first of them (an error is seen; "0" with none).  One batch is
 * pending at a time (a new line takes its place).  A line the rig cannot read whole (a time
 * that is not digits, beyond 64 bits, not after the one before; more than MAX_TICKS entries) is
 * answered "error tick: WHY (tick ASKS|T FEEDS|...|T): LINE" and leaves no batch pending. */
#define _GNU_SOURCE
#include "world.h"

#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#define MAX_TICKS 256

static rig_run_t run_line;
static char batch[RIG_LINE_MAX + 1]; /* the pending line, cut into its entries in place */
static char *asks;
static uint64_t at[MAX_TICKS + 1];
static char *feeds[MAX_TICKS + 1];
static int last, next; /* the entry that asks the world again; the next to make */
static int pending, inside;
static char said[1024]; /* the asks' answers last answered: the pending batch's assumption */
static unsigned errors; /* the feeds' errors since the last answer, and the first */
static char first_error[200];

void world_init(rig_run_t run) { run_line = run; }

/* each of `cmds` (';' between) run: their answer lines, as they were printed (to be freed) */
static char *run_each(char *cmds) {
    char *answer = NULL;
    size_t len = 0;
    FILE *real = stdout, *mem = open_memstream(&answer, &len);
    if (!mem) return NULL;
    stdout = mem; /* (glibc: a part's printf goes to the answer) */
    inside = 1;
    for (char *c = cmds, *nxt; c && *c; c = nxt) {
        nxt = strchr(c, ';');
        if (nxt) *nxt++ = 0;
        run_line(c);
    }
    inside = 0;
    fclose(mem);
    stdout = real;
    return answer;
}

/* a tick's feeds into the parts, their errors counted (each answer looked at, however many) */
static void make(int k) {
    char *out = run_each(feeds[k]);
    if (!out && *feeds[k] && !errors++) /* (no memory for the answers: the feeds not made) */
        snprintf(first_error, sizeof first_error, " error no memory for a tick's feeds: not made");
    for (char *a = out, *nxt; a && *a; a = nxt) {
        nxt = strchr(a, '\n');
        if (nxt) *nxt++ = 0;
        if (strncmp(a, "error", 5)) continue;
        if (!errors++) snprintf(first_error, sizeof first_error, " %.190s", a);
    }
    free(out);
}

/* the asks run now, their answers in `out` (';' between; within `size`, as the last) */
static void ask(char *out, size_t size) {
    static char copy[sizeof said];
    size_t used = 0;
    snprintf(copy, sizeof copy, "%s", asks);
    char *answer = run_each(copy);
    for (char *c = answer; c && *c && used + 1 < size; c++)
        out[used++] = *c == '\n' ? (c[1] ? ';' : 0) : *c;
    out[used < size ? used : size - 1] = 0;
    free(answer);
}

static void answer(uint64_t now, int made) {
    printf("tick %llu %d %s|%u%s\n", (unsigned long long)now, made, said, errors, first_error);
    fflush(stdout);
    errors = 0;
    first_error[0] = 0;
    pending = 0;
}

/* T of an entry: digits, within 64 bits, after `after` (-1: the first); 0 when it is not */
static int parse_at(char *entry, uint64_t *t, char **rest, long double after) {
    if (*entry < '0' || *entry > '9') return 0;
    errno = 0;
    unsigned long long v = strtoull(entry, rest, 10);
    if (errno || (**rest && **rest != ' ') || (long double)v <= after) return 0;
    *t = v;
    if (**rest == ' ') (*rest)++;
    return 1;
}

static const char *parse(const char *line) {
    if (strlen(line) >= sizeof batch) return "line too long";
    strcpy(batch, line);
    char *bar = strchr(batch, '|');
    if (!bar) return "no tick";
    *bar = 0;
    asks = batch;
    if (strlen(asks) >= sizeof said) return "asks too long";
    int n = 0;
    for (char *e = bar + 1, *nxt; e; e = nxt, n++) {
        nxt = strchr(e, '|');
        if (nxt) *nxt++ = 0;
        if (n > MAX_TICKS) return "more ticks than the rig takes";
        if (!parse_at(e, &at[n], &feeds[n], n ? (long double)at[n - 1] : -1.0L))
            return "a time that is not digits, beyond 64 bits or not after the one before";
        if (!nxt && *feeds[n]) return "the last entry has feeds (it is a time alone)";
    }
    last = n - 1;
    return NULL;
}

int world_is_tick(const char *line) {
    return !strncmp(line, "tick", 4) && (!line[4] || line[4] == ' ');
}

int world_command(const char *line) {
    if (!world_is_tick(line)) return 0;
    if (inside) { /* (a feed or an ask that is a tick: refused, the batch left as it is) */
        printf("error tick: a tick inside a tick: %.120s\n", line);
        return 1;
    }
    pending = 0; /* (a new batch takes the old one's place, a refused one too) */
    const char *why = parse(line + (line[4] ? 5 : 4));
    if (why) {
        printf("error tick: %s (tick ASKS|T FEEDS|...|T): %.120s\n", why, line);
        return 1;
    }
    next = 0;
    if (last > 0) make(next++); /* (made: ticked on the drives the rig answered) */
    pending = 1;
    return 1;
}

void world_watch(void) {
    static char now_said[sizeof said];
    if (!pending) return;
    uint64_t now = sim_us();
    while (pending && at[next] <= now) {
        if (next == last) { /* (the batch's end) */
            ask(said, sizeof said);
            answer(now, next);
            return;
        }
        ask(now_said, sizeof now_said);
        if (strcmp(now_said, said)) { /* (the drives changed: the world asks again) */
            strcpy(said, now_said);
            answer(now, next);
            return;
        }
        make(next++);
    }
}
