/* Quadrature encoders at the firmware's pins (encoder.h). */
#include "encoder.h"

#include <stdio.h>
#include <string.h>

#include "sim_time.h"

#define EDGE_US 100

static struct encoder {
    char a_port, b_port;
    int a_bit, b_bit;
    int a, b;     /* the phases' levels */
    long pending; /* edges still to make (> 0 forward) */
    long pos;     /* edges made */
    avr_cycle_count_t last; /* the cycle of the newest edge */
} enc[ENCODERS];
static int n_enc;

static void set_a(struct encoder *e, int level) { rig_pin(e->a_port, e->a_bit, e->a = level); }
static void set_b(struct encoder *e, int level) { rig_pin(e->b_port, e->b_bit, e->b = level); }

static avr_cycle_count_t tick(avr_t *a, avr_cycle_count_t when, void *param) {
    (void)a;
    struct encoder *e = param;
    if (e->pending == 0) return 0;
    static const int seq[4][2] = {{0, 0}, {1, 0}, {1, 1}, {0, 1}};
    int i = 0;
    while (seq[i][0] != e->a || seq[i][1] != e->b) i++;
    int dir = e->pending > 0 ? 1 : -1;
    i = (i + dir + 4) % 4;
    if (seq[i][0] != e->a) set_a(e, seq[i][0]);
    else set_b(e, seq[i][1]);
    e->pending -= dir;
    e->pos += dir;
    e->last = avr->cycle; /* (the timer runs at or just after `when`) */
    return when + avr_usec_to_cycles(avr, EDGE_US);
}

int encoder_add(char a_port, int a_bit, char b_port, int b_bit) {
    if (n_enc == ENCODERS) return -1;
    struct encoder *e = &enc[n_enc];
    *e = (struct encoder){a_port, b_port, a_bit, b_bit, 1, 1, 0, 0, 0};
    set_a(e, 1); /* both high: what the pull-ups read at rest */
    set_b(e, 1);
    return n_enc++;
}

int encoder_count(void) { return n_enc; }

void encoder_steps(int k, long steps) {
    struct encoder *e = &enc[k];
    int idle = e->pending == 0;
    e->pending += steps;
    if (idle && e->pending) avr_cycle_timer_register_usec(avr, EDGE_US, tick, e);
}

/* "NAME [K] REST": K (0 when left out) if it names an encoder, the rest's numbers in v */
static int which(const char *cmd, const char *name, long *v, int want) {
    char word[16];
    long x[2];
    int n = sscanf(cmd, "%15s %ld %ld", word, &x[0], &x[1]);
    int k = n - 1 > want ? (int)x[0] : 0;
    if (n < 1 || strcmp(word, name) != 0 || n - 1 < want || k < 0 || k >= n_enc) return -1;
    if (want) *v = x[n - 2];
    return k;
}

int encoder_command(const char *cmd) {
    long v = 0;
    int k;
    if ((k = which(cmd, "enc", &v, 1)) >= 0) {
        encoder_steps(k, v);
        printf("ok\n");
    } else if ((k = which(cmd, "glitch", &v, 0)) >= 0) { /* both phases at once: an edge missed */
        set_a(&enc[k], !enc[k].a);
        set_b(&enc[k], !enc[k].b);
        printf("ok\n");
    } else if ((k = which(cmd, "encpos", &v, 0)) >= 0) {
        printf("encpos %d %ld %.3f\n", k, enc[k].pos, enc[k].last ? board_us_at(enc[k].last) : -1.0);
    } else {
        return 0;
    }
    return 1;
}
