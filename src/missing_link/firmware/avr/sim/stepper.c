/* A stepper driver at the firmware's pins (stepper.h). */
#include "stepper.h"

#include <stdio.h>
#include <string.h>

static char dir_port, en_port;
static int dir_bit, en_bit, present;
static long pos, count, ignored;

static int enabled(void) { return !en_port || !rig_port_bit(en_port, en_bit); }

static void step_hook(struct avr_irq_t *irq, uint32_t value, void *param) {
    (void)irq;
    (void)param;
    if (!value) return;
    if (!enabled()) { /* enable high: the driver is off */
        ignored++;
        return;
    }
    count++;
    pos += rig_port_bit(dir_port, dir_bit) ? 1 : -1;
}

void stepper_add(char step_port, int step_bit, char dport, int dbit, char eport, int ebit) {
    dir_port = dport, dir_bit = dbit, en_port = eport, en_bit = ebit;
    present = 1;
    avr_irq_register_notify(rig_pin_irq(step_port, step_bit), step_hook, NULL);
}

int stepper_command(const char *cmd) {
    if (!present || strcmp(cmd, "stepper") != 0) return 0;
    printf("stepper %ld %d %ld %ld\n", pos, enabled(), count, ignored);
    return 1;
}
