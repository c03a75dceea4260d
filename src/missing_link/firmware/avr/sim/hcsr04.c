/* An HC-SR04 at the firmware's pins (hcsr04.h). */
#include "hcsr04.h"

#include <stdio.h>

#include "sim_time.h"

static int sonar_mm = 1000, present;
static unsigned rangings;
static avr_irq_t *echo_irq;

static avr_cycle_count_t echo_fall(avr_t *a, avr_cycle_count_t when, void *param) {
    (void)a, (void)when, (void)param;
    avr_raise_irq(echo_irq, 0);
    return 0;
}

static avr_cycle_count_t echo_rise(avr_t *a, avr_cycle_count_t when, void *param) {
    (void)a, (void)when, (void)param;
    avr_raise_irq(echo_irq, 1);
    double us = sonar_mm > 0 ? 2.0 * sonar_mm / 1000.0 / 343.42 * 1e6 : 38000.0;
    avr_cycle_timer_register_usec(avr, (uint32_t)(us + 0.5), echo_fall, NULL);
    return 0;
}

static void trig_hook(struct avr_irq_t *irq, uint32_t value, void *param) {
    (void)irq, (void)param;
    static uint32_t last;
    if (last && !value) { /* the trigger pulse ended: the burst, then the echo */
        rangings++;
        avr_cycle_timer_register_usec(avr, 450, echo_rise, NULL);
    }
    last = value;
}

void hcsr04_add(char trig_port, int trig_bit, char echo_port, int echo_bit) {
    present = 1;
    avr_irq_register_notify(rig_pin_irq(trig_port, trig_bit), trig_hook, NULL);
    echo_irq = rig_pin_irq(echo_port, echo_bit);
    avr_raise_irq(echo_irq, 0);
}

int hcsr04_command(const char *cmd) {
    int v;
    if (!present || sscanf(cmd, "hcsr04 %d", &v) != 1) return 0;
    sonar_mm = v;
    printf("ok\n");
    return 1;
}
