/* The SRF02 sonar on the rig's TWI bus (srf02.h). */
#include "srf02.h"

#include <stdio.h>

#include "twi_bus.h"

static struct {
    twi_device_t dev;
    uint8_t index, reg; /* bytes written since the start; the register pointer */
    uint8_t seq_n;      /* how far into the address-change sequence */
    uint16_t range;
    uint64_t busy_until_us;
    int cm, echo;
    int absent; /* taken off the bus: it acknowledges nothing */
    unsigned rangings;
} srf = {.cm = 100, .echo = 1};

static void command_byte(uint8_t b) {
    if (b == 0x50 || b == 0x51 || b == 0x52) {
        int cm = srf.echo ? srf.cm : 0;
        srf.range = b == 0x50 ? (uint16_t)(cm / 2.54) : b == 0x51 ? (uint16_t)cm : (uint16_t)(cm * 58.3);
        srf.busy_until_us = sim_us() + 65000;
        srf.rangings++;
        srf.seq_n = 0;
        return;
    }
    static const uint8_t change[3] = {0xA0, 0xAA, 0xA5};
    if (srf.seq_n < 3 && b == change[srf.seq_n]) {
        srf.seq_n++;
    } else if (srf.seq_n == 3 && !(b & 1) && (b >> 1) >= 0x70 && (b >> 1) <= 0x7F) {
        srf.dev.addr = b >> 1;
        srf.seq_n = 0;
    } else {
        srf.seq_n = 0;
    }
}

static int start(twi_device_t *d, int read) {
    (void)d;
    (void)read;
    srf.index = 0;
    return sim_us() >= srf.busy_until_us && !srf.absent; /* ranging: no acknowledge at all */
}

static void write(twi_device_t *d, uint8_t b) {
    (void)d;
    if (srf.index++ == 0) srf.reg = b;
    else if (srf.reg++ == 0) command_byte(b);
}

static uint8_t read(twi_device_t *d) {
    (void)d;
    switch (srf.reg++) {
    case 0: return 6; /* software revision */
    case 1: return 0x80;
    case 2: return (uint8_t)(srf.range >> 8);
    case 3: return (uint8_t)srf.range;
    case 5: return 18;
    default: return 0;
    }
}

void srf02_add(uint8_t addr) {
    srf.dev = (twi_device_t){.addr = addr, .start = start, .write = write, .read = read};
    twi_bus_add(&srf.dev);
}

void srf02_stats(unsigned *rangings, uint8_t *addr) {
    *rangings = srf.rangings;
    *addr = srf.dev.addr;
}

int srf02_command(const char *cmd) {
    int v;
    if (sscanf(cmd, "srf02 %d", &v) == 1) srf.cm = v;
    else if (sscanf(cmd, "srf02_absent %d", &v) == 1) srf.absent = v;
    else if (sscanf(cmd, "echo %d", &v) == 1) srf.echo = v;
    else return 0;
    printf("ok\n");
    return 1;
}
