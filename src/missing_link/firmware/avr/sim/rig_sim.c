/* Real AVR machine code in a modelled rig: simavr runs the firmware's ELF, its UART is bridged to
 * a pseudo-terminal (simavr's uart_pty part), and the parts are modelled at the pins and buses,
 * each in a file of its own:
 *   analog.c   a Sharp GP2Y0A02YK's voltage on an ADC input, any voltage on another (a battery)
 *   twi_bus.c  the TWI bus, and on it srf02.c (an SRF02 sonar) and mpu6050.c (an IMU)
 *   encoder.c  quadrature encoders (edges on their phases' pins)
 *   probes.c   what the rig measures: the servo's frame and pulse (OC1A), the trigger's edges
 *              (OC2A), ADC0's conversions, the lowest stack pointer, the board's clock, the
 *              longest stretches with interrupts off
 *   motor.c    DC motors at Timer0's outputs, and the wheels they turn (an encoder each)
 *   stepper.c, hcsr04.c, gps.c  a stepper driver, an HC-SR04, a GPS receiver on USART1
 *   eeprom.c   the EEPROM across power cycles, and power cuts
 *   link.c     the board's link: simavr's uart_pty, and the AVR held while its FIFO is nearly
 *              full (its thread runs late: a busy machine), so that no byte is lost
 *   world.c    a world beside the rig (virtual/world_avr.py): its batches of ticks, each tick's
 *              readings into the parts at its simulated time
 *
 *   rig_sim FIRMWARE.elf [--mcu atmega328p] [--skew-ppm P] [--eeprom FILE] [--part SPEC]...
 *
 * --part SPEC: a part at the firmware's pins (deploy/avrsim.py writes them from a board file;
 * pins as port and bit: D2, PK0):
 *   quadrature PIN_A PIN_B     an encoder
 *   sharp CH                   a Sharp on ADC channel CH
 *   ain CH MV                  MV millivolts on ADC channel CH (a battery's divider)
 *   srf02 ADDR, mpu6050 ADDR   an SRF02 (0x70), an MPU-6050 (0x68) on the TWI
 *   motor OUT DIR              a motor on Timer0's output OUT (0: OC0A, 1: OC0B) with its
 *                              direction pin; motor 2 -: on both (IN1/IN2)
 *   wheel MOTOR ENCODER CPR TOP  motor MOTOR (the k-th added) turns encoder ENCODER: CPR edges
 *                              a turn, TOP turns/s at full drive
 *   stepper STEP DIR EN        a stepper driver (EN -: none)
 *   hcsr04 TRIG ECHO           an HC-SR04
 *   gps PPS                    a GPS receiver on USART1 (PPS -: no PPS pin)
 * Without any, the thesis rig: a Sharp on ADC0, an SRF02 at 0x70 and an encoder on INT0/INT1.
 * --eeprom FILE (eeprom.c): the EEPROM's contents are read from FILE at power-up (when it
 * exists) and written back when the rig is powered off (quit, stdin closed), as a real EEPROM
 * keeps them.
 * Prints "PTY /dev/pts/N" when the board runs.  Simulated time is paced to the host's
 * CLOCK_MONOTONIC times (1 + P * 1e-6): the board's crystal runs P ppm fast, the known skew clock
 * sync must find.
 *
 * The control channel: lines on stdin, each answered with one line on stdout.  Each part's
 * header says its lines; the rig's own:
 *   lag: "lag US", the furthest simulated time fell behind the host's since last asked
 *   stats: "stats sim_us T host_ns T cycles N rangings N srf02_addr A pc P twi N last M"
 *   peek ADDR: "peek B0 B1 B2 B3", four bytes of the AVR's data space from ADDR (hex)
 *   cut N: the power goes after the next N bytes written to the EEPROM (a byte written by the
 *          firmware that changes it: avr-libc's eeprom_update_* writes only those): the EEPROM
 *          is saved as it is then and the rig stops at once, printing "CUT"
 *   quit: the power goes (the EEPROM saved)
 *   tick ASKS|T0 FEEDS|T1 FEEDS|...|TN: a world's batch of ticks (virtual/world_avr.py), one
 *          line each way a batch: each tick's readings go into the parts at its simulated time
 *          while the drives read as the world assumed, and the rig answers "tick SIM_US MADE
 *          ASKS'ANSWERS|ERRORS FIRST_ERROR" where they do not, or at the batch's end (world.c)
 * A line no part takes is answered "error unknown command: LINE"; a line longer than
 * RIG_LINE_MAX bytes (world.h: a batch's line fits) is refused whole, "error line of N bytes,
 * over the rig's RIG_LINE_MAX: refused: ..." ("error tick: ..." for a `tick` line, so that its
 * world sees it). */
#define _GNU_SOURCE
#include <fcntl.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <unistd.h>

#include "avr_ioport.h"
#include "parts/uart_pty.h"
#include "sim_elf.h"
#include "analog.h"
#include "eeprom.h"
#include "encoder.h"
#include "mpu6050.h"
#include "gps.h"
#include "link.h"
#include "hcsr04.h"
#include "motor.h"
#include "probes.h"
#include "srf02.h"
#include "stepper.h"
#include "twi_bus.h"
#include "world.h"

static uart_pty_t uart;
static double skew;
static double worst_lag_us; /* how far simulated time fell behind the host's (a loaded machine) */
static uint64_t start_ns;

static uint64_t mono_ns(void) {
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (uint64_t)ts.tv_sec * 1000000000ull + (uint64_t)ts.tv_nsec;
}

/* ---- control channel and pacing ---------------------------------------------------------------- */
static rig_command_t parts[16];
static int n_parts;

static void command(const char *cmd);

static int rig_command(const char *cmd) {
    unsigned v, rangings, msgs;
    uint32_t last;
    uint8_t addr;
    if (!strncmp(cmd, "lag", 3)) { /* the worst since last asked */
        printf("lag %.0f\n", worst_lag_us);
        worst_lag_us = 0;
    } else if (!strncmp(cmd, "stats", 5)) {
        srf02_stats(&rangings, &addr);
        twi_bus_stats(&msgs, &last);
        printf("stats sim_us %llu host_ns %llu cycles %llu rangings %u srf02_addr 0x%02x pc 0x%x "
               "twi %u last 0x%08x\n",
               (unsigned long long)sim_us(), (unsigned long long)mono_ns(),
               (unsigned long long)avr->cycle, rangings, addr, (unsigned)avr->pc, msgs,
               (unsigned)last);
    } else if (sscanf(cmd, "peek %x", &v) == 1 && v + 3 <= avr->ramend) {
        printf("peek %02x %02x %02x %02x\n", avr->data[v], avr->data[v + 1], avr->data[v + 2],
               avr->data[v + 3]);
    } else if (sscanf(cmd, "cut %u", &v) == 1 && v > 0) {
        eeprom_cut((int)v);
        printf("ok\n");
    } else if (!strncmp(cmd, "quit", 4)) {
        power_off();
    } else {
        return 0;
    }
    return 1;
}

static void command(const char *cmd) {
    int i = 0;
    while (i < n_parts && !parts[i](cmd)) i++;
    if (i == n_parts) printf("error unknown command: %s\n", cmd);
}

/* a line longer than RIG_LINE_MAX: refused whole, said (a `tick` line's refusal to the world) */
static void refuse_long(const char *line, size_t n) {
    printf("error%s line of %zu bytes, over the rig's %d: refused: %.60s...\n",
           world_is_tick(line) ? " tick:" : "", n, RIG_LINE_MAX, line);
}

static void poll_stdin(void) {
    static char line[RIG_LINE_MAX + 1];
    static size_t line_n;
    char buf[4096]; /* (all that came at once: a byte a read was a system call a byte) */
    ssize_t r;
    while ((r = read(0, buf, sizeof buf)) > 0) {
        for (ssize_t i = 0; i < r; i++) {
            if (buf[i] == '\n') {
                line[line_n < RIG_LINE_MAX ? line_n : RIG_LINE_MAX] = 0;
                if (line_n > RIG_LINE_MAX) refuse_long(line, line_n);
                else command(line);
                line_n = 0;
            } else {
                if (line_n < RIG_LINE_MAX) line[line_n] = buf[i];
                line_n++; /* (counted on past the end: the line is refused whole) */
            }
        }
    }
    fflush(stdout); /* (the answers to all that came: one write) */
    if (r == 0) power_off(); /* stdin closed: the test is gone */
}

static void pace(void) {
    /* simulated µs must not run ahead of host µs * (1 + skew) */
    double host_us = (double)(mono_ns() - start_ns) / 1000.0 * (1.0 + skew);
    double ahead = (double)sim_us() - host_us;
    if (-ahead > worst_lag_us) worst_lag_us = -ahead;
    if (ahead > 50) usleep((useconds_t)(ahead / (1.0 + skew)));
}

/* ---- start-up ------------------------------------------------------------------------------------ */
/* simavr 1.6 models the Mega 2560's pin-change interrupts on port B only (PCINT0); port K's
 * (A8-A15: PCINT16-23, PCMSK2, PCIE2/PCIF2, vector 11), which the datasheet has and the
 * firmware uses (an encoder's phases, an echo), is given the same wiring here. */
static void mega_port_k_pcint(void) {
    for (avr_io_t *io = avr->io_port; io; io = io->next) {
        avr_ioport_t *p = (avr_ioport_t *)io;
        if (strcmp(io->kind, "port") != 0 || p->name != 'K') continue;
        p->r_pcint = 0x6D;                                        /* PCMSK2 */
        p->pcint.enable = (avr_regbit_t)AVR_IO_REGBIT(0x68, 2);   /* PCICR: PCIE2 */
        p->pcint.raised = (avr_regbit_t)AVR_IO_REGBIT(0x3B, 2);   /* PCIFR: PCIF2 */
        p->pcint.vector = 11;                                     /* PCINT2_vect */
        avr_register_vector(avr, &p->pcint);
    }
}

static int load(const char *elf, const char *mcu, const char *eeprom_file) {
    elf_firmware_t f;
    memset(&f, 0, sizeof f);
    if (elf_read_firmware(elf, &f) != 0) {
        fprintf(stderr, "rig_sim: cannot read %s\n", elf);
        return 0;
    }
    strncpy(f.mmcu, mcu, sizeof f.mmcu - 1);
    f.frequency = 16000000;
    f.vcc = f.avcc = f.aref = 5000;
    avr = avr_make_mcu_by_name(mcu);
    if (!avr) {
        fprintf(stderr, "rig_sim: simavr has no %s\n", mcu);
        return 0;
    }
    avr_init(avr);
    avr_load_firmware(avr, &f);
    avr->log = 0;
    if (!strcmp(mcu, "atmega2560")) mega_port_k_pcint();
    eeprom_open(avr, eeprom_file);
    uart_pty_init(avr, &uart);
    char which = strcmp(mcu, "atmega32u4") ? '0' : '1';
    uart_pty_connect(&uart, which);
    link_watch(&uart, which);
    return 1;
}

/* pin k of a spec ("-": none, port 0) */
static int pin_at(char words[][8], int k, char *port, int *bit) {
    if (!strcmp(words[k], "-")) return *port = 0, *bit = 0, 1;
    return rig_parse_pin(words[k], port, bit);
}

/* one --part SPEC: 0 if it is not one */
static int add_part(const char *spec) {
    char kind[16], w[4][8], p[4] = {0};
    int b[4] = {0};
    unsigned v, mv;
    double cpr, top;
    int n = sscanf(spec, "%15s %7s %7s %7s %7s", kind, w[0], w[1], w[2], w[3]) - 1;
    for (int k = 0; k < n && k < 3; k++) pin_at(w, k, &p[k], &b[k]); /* (where they are pins) */
    if (n == 2 && !strcmp(kind, "quadrature") && p[0] && p[1]) return encoder_add(p[0], b[0], p[1], b[1]) >= 0;
    if (n == 1 && !strcmp(kind, "sharp") && sscanf(w[0], "%u", &v) == 1 && v < 16) sharp_add((int)v);
    else if (n == 2 && !strcmp(kind, "ain") && sscanf(w[0], "%u", &v) == 1 && sscanf(w[1], "%u", &mv) == 1)
        return ain_add((int)v, mv);
    else if (n == 1 && !strcmp(kind, "srf02") && sscanf(w[0], "%x", &v) == 1 && v < 128) srf02_add((uint8_t)v);
    else if (n == 1 && !strcmp(kind, "mpu6050") && sscanf(w[0], "%x", &v) == 1 && v < 128)
        mpu6050_add((uint8_t)v);
    else if (n == 2 && !strcmp(kind, "motor") && sscanf(w[0], "%u", &v) == 1 && pin_at(w, 1, &p[1], &b[1]))
        return motor_add((int)v, p[1], b[1]);
    else if (n == 4 && !strcmp(kind, "wheel") && sscanf(w[2], "%lf", &cpr) == 1 &&
             sscanf(w[3], "%lf", &top) == 1)
        return wheel_add(atoi(w[0]), atoi(w[1]), cpr, top);
    else if (n == 3 && !strcmp(kind, "stepper") && p[0] && p[1] && pin_at(w, 2, &p[2], &b[2]))
        stepper_add(p[0], b[0], p[1], b[1], p[2], b[2]);
    else if (n == 2 && !strcmp(kind, "hcsr04") && p[0] && p[1]) hcsr04_add(p[0], b[0], p[1], b[1]);
    else if (n == 1 && !strcmp(kind, "gps") && pin_at(w, 0, &p[0], &b[0])) gps_add(p[0], b[0]);
    else return 0;
    return 1;
}

/* the parts of --part, else the thesis rig's */
static int wire(const char *mcu, const char **specs, int n_specs) {
    int uno = !strcmp(mcu, "atmega328p"); /* INT0/INT1: PD2/PD3; Mega and Leonardo: PD0/PD1 */
    static const rig_command_t commands[] = {rig_command, world_command, probes_command, analog_command,
        srf02_command, encoder_command, mpu6050_command, motor_command, stepper_command,
        hcsr04_command, gps_command, link_command};
    world_init(command);
    probes_init(mcu);
    motor_init(mcu);
    twi_bus_init();
    for (int i = 0; i < n_specs; i++) {
        if (!add_part(specs[i])) {
            fprintf(stderr, "rig_sim: --part %s: not a part the rig has\n", specs[i]);
            return 0;
        }
    }
    if (!n_specs) {
        sharp_add(0);
        srf02_add(0x70);
        encoder_add('D', uno ? 2 : 0, 'D', uno ? 3 : 1);
    }
    for (size_t i = 0; i < sizeof commands / sizeof commands[0]; i++) parts[n_parts++] = commands[i];
    return 1;
}

int main(int argc, char **argv) {
    const char *elf = NULL, *mcu = "atmega328p", *eeprom_file = NULL, *specs[32];
    int n_specs = 0;
    for (int i = 1; i < argc; i++) {
        if (!strcmp(argv[i], "--mcu") && i + 1 < argc) mcu = argv[++i];
        else if (!strcmp(argv[i], "--skew-ppm") && i + 1 < argc) skew = atof(argv[++i]) * 1e-6;
        else if (!strcmp(argv[i], "--eeprom") && i + 1 < argc) eeprom_file = argv[++i];
        else if (!strcmp(argv[i], "--part") && i + 1 < argc && n_specs < 32) specs[n_specs++] = argv[++i];
        else elf = argv[i];
    }
    if (!elf) {
        fprintf(stderr, "usage: rig_sim FIRMWARE.elf [--mcu atmega328p] [--skew-ppm P] [--eeprom FILE] "
                        "[--part SPEC]...\n");
        return 2;
    }
    if (!load(elf, mcu, eeprom_file) || !wire(mcu, specs, n_specs)) return 1;
    fcntl(0, F_SETFL, fcntl(0, F_GETFL) | O_NONBLOCK);
    printf("PTY %s\n", uart.port[0].slavename);
    fflush(stdout);
    start_ns = mono_ns();
    int holding = 0;
    for (unsigned long n = 0;; n++) {
        /* (link.h: the pty's thread runs late.  Looked at every 8192 passes while the AVR
         * runs, about 0.5 ms of its time: fewer bytes than the FIFO's margin even at 1 Mbaud,
         * and no system call per instruction when a pty nobody reads keeps the FIFO full) */
        if ((holding || (n & 8191) == 0) && (holding = link_backed_up())) {
            usleep(100);
            poll_stdin();
            continue;
        }
        int state = avr_run(avr);
        if (state == cpu_Done || state == cpu_Crashed) {
            fprintf(stderr, "rig_sim: the AVR stopped (state %d)\n", state);
            return 1;
        }
        probes_watch();
        if (cut_left > 0) eeprom_watch();
        if ((n & 1023) == 0) {
            pace();
            poll_stdin();
            world_watch();
        }
    }
}
