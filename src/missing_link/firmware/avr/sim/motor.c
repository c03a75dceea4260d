/* DC motors and the wheels they turn (motor.h). */
#include "motor.h"

#include <math.h>
#include <stdio.h>
#include <string.h>

#include "encoder.h"
#include "sim_time.h"

#define MOTORS 4
#define WHEELS 4
#define WHEEL_TAU_S 0.1 /* a small geared motor's: most of its speed in 0.3 s */
#define STEP_US 1000
enum { TCCR0A = 0x44, OCR0A = 0x47, OCR0B = 0x48 };

static char oc_port[2] = {'D', 'D'};
static int oc_bit[2] = {6, 5}; /* OC0A, OC0B: Uno PD6/PD5; Mega PB7/PG5 */
static struct {
    int out;
    char dir_port;
    int dir_bit;
} motors[MOTORS];
static int n_motors;
static struct {
    int motor, encoder, on;
    double cpr, top; /* edges a turn, turns/s at full drive */
    double speed, turns; /* turns/s, turns */
    long edges;          /* edges asked of the encoder so far */
} wheels[WHEELS];
static int n_wheels;

static double output(int b) { /* one of Timer0's outputs, 0..1 */
    uint8_t com = avr->data[TCCR0A] >> (b ? 4 : 6) & 3;
    if (com == 2) return (avr->data[b ? OCR0B : OCR0A] + 1) / 256.0;
    return rig_port_bit(oc_port[b], oc_bit[b]);
}

static double drive(int k) { /* -1..1: < 0 turning back */
    if (motors[k].out == 2) return output(0) - output(1);
    double d = output(motors[k].out);
    return rig_port_bit(motors[k].dir_port, motors[k].dir_bit) ? -d : d;
}

static avr_cycle_count_t step(avr_t *a, avr_cycle_count_t when, void *param) {
    (void)a;
    (void)param;
    double dt = STEP_US * 1e-6;
    for (int i = 0; i < n_wheels; i++) {
        double want = drive(wheels[i].motor) * wheels[i].top;
        wheels[i].speed += (want - wheels[i].speed) * (1 - exp(-dt / WHEEL_TAU_S));
        wheels[i].turns += wheels[i].speed * dt;
        long edges = lround(floor(wheels[i].turns * wheels[i].cpr));
        if (wheels[i].on && edges != wheels[i].edges) encoder_steps(wheels[i].encoder, edges - wheels[i].edges);
        wheels[i].edges = edges;
    }
    return when + avr_usec_to_cycles(avr, STEP_US);
}

void motor_init(const char *mcu) {
    if (!strcmp(mcu, "atmega2560")) {
        oc_port[0] = 'B', oc_bit[0] = 7;
        oc_port[1] = 'G', oc_bit[1] = 5;
    }
}

int motor_add(int out, char dir_port, int dir_bit) {
    if (n_motors == MOTORS || out < 0 || out > 2) return 0;
    motors[n_motors].out = out;
    motors[n_motors].dir_port = dir_port;
    motors[n_motors++].dir_bit = dir_bit;
    return 1;
}

int wheel_add(int motor, int encoder, double cpr, double top) {
    if (n_wheels == WHEELS || motor < 0 || motor >= n_motors || encoder < 0 ||
        encoder >= encoder_count() || !(cpr > 0) || !(top > 0))
        return 0;
    wheels[n_wheels].motor = motor;
    wheels[n_wheels].encoder = encoder;
    wheels[n_wheels].cpr = cpr;
    wheels[n_wheels].top = top;
    wheels[n_wheels++].on = 1;
    if (n_wheels == 1) avr_cycle_timer_register_usec(avr, STEP_US, step, NULL);
    return 1;
}

int motor_command(const char *cmd) {
    int k;
    char on[8];
    if (!strcmp(cmd, "motor")) {
        printf("motor");
        for (int i = 0; i < n_motors; i++) printf(" %.4f %d", fabs(drive(i)), drive(i) < 0);
        printf("\n");
    } else if (!strcmp(cmd, "wheels")) {
        printf("wheels");
        for (int i = 0; i < n_wheels; i++) printf(" %d %.6f %.6f", i, wheels[i].turns, wheels[i].speed);
        printf("\n");
    } else if (sscanf(cmd, "wheel %d %7s", &k, on) == 2 && k >= 0 && k < n_wheels &&
               (!strcmp(on, "on") || !strcmp(on, "off"))) {
        wheels[k].on = !strcmp(on, "on");
        printf("ok\n");
    } else {
        return 0;
    }
    return 1;
}
