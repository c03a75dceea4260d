/* The thesis rig around real AVR machine code: simavr runs the firmware's ELF, its UART is
 * bridged to a pseudo-terminal (simavr's uart_pty part), and the rig is modelled at the pins and
 * buses: a Sharp GP2Y0A02YK's voltage on an ADC input, an SRF02 as a TWI device (registers,
 * no acknowledge while ranging, the address-change sequence), quadrature edges on INT0/INT1,
 * and the servo's frame on OC1A with its pulse width from the timer's registers.
 *
 *   rig_sim FIRMWARE.elf [--mcu atmega328p] [--skew-ppm P] [--eeprom FILE] [--rover]
 *
 * --rover (with --mcu atmega2560): the rover's parts too (rover.c: motors, a stepper, an
 * HC-SR04 and a GPS at examples/boards/rover-mega.py's pins).
 *
 * --eeprom FILE (eeprom.c): the EEPROM's contents are read from FILE at power-up (when it
 * exists) and written back when the rig is powered off (quit, stdin closed), as a real EEPROM
 * keeps them.
 * Prints "PTY /dev/pts/N" when the board runs.  Simulated time is paced to the host's
 * CLOCK_MONOTONIC times (1 + P * 1e-6): the board's crystal runs P ppm fast, the known skew clock
 * sync must find.  Control lines on stdin (each answered with one line on stdout):
 *   sharp MM | ain CH MV | srf02 CM | echo 0/1 | enc STEPS | glitch | pulse | stats | peek ADDR | quit
 *   ain CH MV: MV millivolts on ADC channel CH (1..7; ADC0 is the Sharp's), e.g. a battery's divider
 *   srf02_absent 1/0: the SRF02 taken off the bus (no acknowledge at all), or put back
 *   lag: "lag US", the furthest simulated time fell behind the host's since last asked
 *   trig: the trigger pin's edges (OC2A: Uno D11 / Mega D10): "trig EDGES RISE_US FALL_US", the last
 *         edges in the board's µs (its clock: Timer1, counted from the cycle it was started)
 *   adc: "adc N T1 T2 ...": the starts of the last conversions of ADC0, in the board's µs
 *   stack: "stack MIN_SP PC": the lowest the stack pointer has been, and where (a byte address)
 *   cut N: the power goes after the next N bytes written to the EEPROM (a byte written by
 *          the firmware that changes it: avr-libc's eeprom_update_* writes only those): the
 *          EEPROM is saved as it is then and the rig stops at once, printing "CUT"
 */
#define _GNU_SOURCE
#include <fcntl.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <unistd.h>

#include "avr_adc.h"
#include "avr_ioport.h"
#include "avr_twi.h"
#include "parts/uart_pty.h"
#include "sim_avr.h"
#include "sim_elf.h"
#include "sim_time.h"
#include "eeprom.h"
#include "rover.h"

static avr_t *avr;
static int rover; /* --rover: the rover's parts (rover.c) on a Mega */
static uart_pty_t uart;
static double skew;
static double worst_lag_us; /* how far simulated time fell behind the host's (a loaded machine) */
static uint64_t start_ns;
static const char *eeprom_file; /* --eeprom */

static uint64_t mono_ns(void) {
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (uint64_t)ts.tv_sec * 1000000000ull + (uint64_t)ts.tv_nsec;
}

static uint64_t sim_us(void) { return avr->cycle / (avr->frequency / 1000000); }

/* ---- Sharp: the datasheet curve (cm, V), linear between points (not the firmware's table) ---- */
static const double sharp_curve[][2] = {
    {0, 0.0},    {5, 1.6},     {10, 2.35},  {15, 2.75},  {20, 2.5},   {30, 2.0},
    {40, 1.55},  {50, 1.25},   {60, 1.05},  {70, 0.9},   {80, 0.8},   {90, 0.72},
    {100, 0.65}, {120, 0.55},  {150, 0.41}, {200, 0.35}, {300, 0.3},
};
static int sharp_mm = 800;

static void sharp_update(void) {
    double cm = sharp_mm / 10.0, v = 0.3;
    size_t n = sizeof sharp_curve / sizeof sharp_curve[0];
    for (size_t i = 1; i < n; i++) {
        if (cm <= sharp_curve[i][0]) {
            double c0 = sharp_curve[i - 1][0], v0 = sharp_curve[i - 1][1];
            v = v0 + (sharp_curve[i][1] - v0) * (cm - c0) / (sharp_curve[i][0] - c0);
            break;
        }
    }
    avr_raise_irq(avr_io_getirq(avr, AVR_IOCTL_ADC_GETIRQ, ADC_IRQ_ADC0), (uint32_t)lround(v * 1000));
}

/* ---- SRF02 on the TWI bus -------------------------------------------------------------------- */
static struct {
    avr_irq_t *irq;
    uint8_t addr; /* 7 bit */
    uint8_t selected, index, reg;
    uint8_t seq[4], seq_n;
    uint16_t range;
    uint64_t busy_until_us;
    int cm, echo;
    int absent; /* taken off the bus: it acknowledges nothing */
    unsigned rangings, msgs;
    uint32_t last_msg;
} srf = {.addr = 0x70, .cm = 100, .echo = 1};

static void srf_write(uint8_t reg, uint8_t b) {
    if (reg != 0) return;
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
        srf.seq[srf.seq_n++] = b;
    } else if (srf.seq_n == 3 && !(b & 1) && (b >> 1) >= 0x70 && (b >> 1) <= 0x7F) {
        srf.addr = b >> 1;
        srf.seq_n = 0;
    } else {
        srf.seq_n = 0;
    }
}

static uint8_t srf_read(uint8_t reg) {
    switch (reg) {
    case 0: return 6; /* software revision */
    case 1: return 0x80;
    case 2: return (uint8_t)(srf.range >> 8);
    case 3: return (uint8_t)srf.range;
    case 5: return 18;
    default: return 0;
    }
}

static void srf_hook(struct avr_irq_t *irq, uint32_t value, void *param) {
    (void)irq;
    (void)param;
    avr_twi_msg_irq_t v;
    v.u.v = value;
    srf.msgs++;
    srf.last_msg = value;
    avr_irq_t *to_avr = avr_io_getirq(avr, AVR_IOCTL_TWI_GETIRQ(0), TWI_IRQ_INPUT);
    if (v.u.twi.msg & TWI_COND_STOP) srf.selected = 0;
    if (v.u.twi.msg & TWI_COND_START) {
        srf.selected = 0;
        srf.index = 0;
        int busy = sim_us() < srf.busy_until_us; /* ranging: no acknowledge at all */
        if ((v.u.twi.addr >> 1) == srf.addr && !busy && !srf.absent) {
            srf.selected = v.u.twi.addr;
            avr_raise_irq(to_avr, avr_twi_irq_msg(TWI_COND_ACK, srf.selected, 1));
        }
    }
    if (!srf.selected) return;
    if (v.u.twi.msg & TWI_COND_WRITE) {
        avr_raise_irq(to_avr, avr_twi_irq_msg(TWI_COND_ACK, srf.selected, 1));
        if (srf.index++ == 0) srf.reg = v.u.twi.data;
        else srf_write(srf.reg++, v.u.twi.data);
    }
    if (v.u.twi.msg & TWI_COND_READ) {
        avr_raise_irq(to_avr, avr_twi_irq_msg(TWI_COND_READ, srf.selected, srf_read(srf.reg++)));
    }
}

/* ---- encoder: one edge every 100 µs of simulated time ----------------------------------------- */
static int enc_pending, enc_a = 1, enc_b = 1; /* both high: what the pull-ups read at rest */
static uint8_t enc_port = 'D', enc_pin_a = 2, enc_pin_b = 3;

static void enc_set(uint8_t pin, int level) {
    avr_raise_irq(avr_io_getirq(avr, AVR_IOCTL_IOPORT_GETIRQ(enc_port), pin), level);
}

static avr_cycle_count_t enc_tick(avr_t *a, avr_cycle_count_t when, void *param) {
    (void)a;
    (void)param;
    if (enc_pending == 0) return 0;
    static const int seq[4][2] = {{0, 0}, {1, 0}, {1, 1}, {0, 1}};
    int i = 0;
    while (seq[i][0] != enc_a || seq[i][1] != enc_b) i++;
    int dir = enc_pending > 0 ? 1 : -1;
    i = (i + dir + 4) % 4;
    if (seq[i][0] != enc_a) enc_set(enc_pin_a, enc_a = seq[i][0]);
    else enc_set(enc_pin_b, enc_b = seq[i][1]);
    enc_pending -= dir;
    return when + avr_usec_to_cycles(avr, 100);
}

/* ---- servo: OC1A ---------------------------------------------------------------------------------
 * The frame period is measured at the pin (rising edges).  The pulse width is read from the
 * timer's registers as the hardware would produce it (OCR1A ticks at the prescaled clock, output
 * enabled by COM1A1 and DDR): simavr 1.6 raises OC1A at each frame but drops it again within a
 * few cycles whatever OCR1A holds, so the pin's high time says nothing about the width. */
static uint8_t servo_port = 'B', servo_pin = 1;
static avr_cycle_count_t servo_rise, servo_period;
static unsigned servo_frames;

static void servo_hook(struct avr_irq_t *irq, uint32_t value, void *param) {
    (void)irq;
    (void)param;
    if (value) {
        if (servo_rise) servo_period = avr->cycle - servo_rise;
        servo_rise = avr->cycle;
        servo_frames++;
    }
}

static double servo_pulse_us(void) {
    enum { TCCR1A = 0x80, TCCR1B = 0x81, OCR1AL = 0x88, DDRB = 0x24 };
    static const unsigned prescale[8] = {0, 1, 8, 64, 256, 1024, 0, 0};
    unsigned ps = prescale[avr->data[TCCR1B] & 7];
    if (!(avr->data[TCCR1A] & 0x80) || !(avr->data[DDRB] & (1u << servo_pin)) || !ps) return 0;
    unsigned ocr = avr->data[OCR1AL] | (avr->data[OCR1AL + 1] << 8);
    return (double)ocr * ps * 1e6 / avr->frequency;
}

/* ---- the board's clock, the trigger's pin, ADC0's conversions, the stack --------------------------
 * The firmware's clock is Timer1 at 2 MHz from the moment TCCR1B's clock bits are set: that
 * cycle (seen after the instruction that set them, at most 2 cycles late) is its zero, so an
 * event at the pins can be put in the board's µs to compare with the ticks it was asked for. */
static avr_cycle_count_t t1_start;
static uint8_t trig_pin = 3; /* OC2A: PB3 */
static avr_cycle_count_t trig_rise, trig_fall;
static unsigned trig_edges;
#define ADC_LOG 64
static avr_cycle_count_t adc_starts[ADC_LOG];
static unsigned adc_n;
static uint16_t sp_min = 0xFFFF;
static uint32_t sp_min_pc; /* where it was reached */

static double board_us_at(avr_cycle_count_t c) {
    return c < t1_start ? -1.0 : (double)(c - t1_start) * 1e6 / avr->frequency;
}


/* OC2A (the trigger's pin) as the datasheet has it, from the registers: Timer2 counts from the
 * cycle its clock was started, one count per 8 cycles (prescaler 8, the only one the firmware
 * uses); a compare match (the count going from OCR2A to OCR2A + 1) applies COM2A to the pin:
 * toggle, clear or set; COM2A = 0 hands the pin back to PORTB.  A write of FOC2A (TCCR2B bit 7,
 * a strobe that reads 0: the rig clears it) forces that at once, without a flag, as the datasheet
 * has it (simavr 1.6 ignores it).  The rig does not take the pin
 * from simavr's timer: 1.6 also drives it at every overflow in normal mode (its PWM modes'
 * behaviour; fixed upstream since).  Checked after every instruction with the registers as they
 * were before it, so a match is placed on its exact cycle. */
static avr_cycle_count_t t2_start, t2_seen;
static uint8_t oc2a, trig_level, ocr2a_was, com2a_was;

static void trig_edge(uint8_t level, avr_cycle_count_t at) {
    if (level == trig_level) return;
    trig_level = level;
    trig_edges++;
    if (level) trig_rise = at;
    else trig_fall = at;
}

/* a compare match (or one forced) with compare mode `com`: toggle, clear or set; 0: none */
static void oc2a_apply(uint8_t com, avr_cycle_count_t at) {
    if (!com) return;
    if (com == 1) oc2a ^= 1;
    else if (com == 2) oc2a = 0;
    else oc2a = 1;
    trig_edge(oc2a, at);
}

static void trig_watch(void) {
    enum { TCCR2A = 0xB0, TCCR2B = 0xB1, OCR2A = 0xB3, PORTB = 0x25 };
    if (!t2_start) {
        if ((avr->data[TCCR2B] & 7) != 2) return;
        t2_start = t2_seen = avr->cycle;
    }
    uint64_t n0 = (t2_seen - t2_start) / 8, n1 = (avr->cycle - t2_start) / 8; /* counts so far */
    if (com2a_was && n1 > n0) {
        uint64_t to = (uint64_t)((uint8_t)(ocr2a_was + 1) - (uint8_t)(n0 + 1)) & 0xFF; /* counts */
        if (to < n1 - n0) oc2a_apply(com2a_was, t2_start + (n0 + 1 + to) * 8); /* the count reached OCR2A + 1 */
    }
    t2_seen = avr->cycle;
    ocr2a_was = avr->data[OCR2A];
    com2a_was = avr->data[TCCR2A] >> 6;
    if (avr->data[TCCR2B] & 0x80) { /* FOC2A: a strobe (it reads 0), the compare mode applied now */
        avr->data[TCCR2B] &= 0x7F;
        oc2a_apply(com2a_was, avr->cycle);
    }
    if (!com2a_was) trig_edge((avr->data[PORTB] >> trig_pin) & 1, avr->cycle);
}

static void adc_hook(struct avr_irq_t *irq, uint32_t value, void *param) {
    (void)irq;
    (void)param;
    /* an avr_adc_mux_t's bits (kind 0-2, gain, diff, src 19-31) in the low 32 */
    if ((value & 7) == ADC_MUX_SINGLE && (value >> 19) == 0) adc_starts[adc_n++ % ADC_LOG] = avr->cycle;
}

/* after every instruction */
static void watch(void) {
    if (!t1_start && (avr->data[0x81] & 7)) t1_start = avr->cycle; /* TCCR1B */
    trig_watch();
    uint16_t sp = (uint16_t)(avr->data[0x5D] | (avr->data[0x5E] << 8));
    /* SPH is written before SPL (with SREG restored between): no reading until SPL is too */
    int half = 0;
    for (int k = 0; k < 4; k += 2) {
        uint16_t op = (uint16_t)(avr->flash[avr->pc + k] | (avr->flash[avr->pc + k + 1] << 8));
        half |= (op & 0xFE0F) == 0xBE0D; /* out 0x3d (SPL), rN */
    }
    if (!half && sp < sp_min && sp > 0x100) {
        sp_min = sp;
        sp_min_pc = avr->pc;
    }
}

/* ---- control channel and pacing ---------------------------------------------------------------- */
static char line[256];
static size_t line_n;

static void command(const char *cmd) {
    int v, mv;
    if (rover && rover_command(cmd)) {
    } else if (sscanf(cmd, "sharp %d", &v) == 1) {
        sharp_mm = v;
        sharp_update();
        printf("ok\n");
    } else if (sscanf(cmd, "srf02 %d", &v) == 1) {
        srf.cm = v;
        printf("ok\n");
    } else if (sscanf(cmd, "srf02_absent %d", &v) == 1) {
        srf.absent = v;
        printf("ok\n");
    } else if (sscanf(cmd, "echo %d", &v) == 1) {
        srf.echo = v;
        printf("ok\n");
    } else if (sscanf(cmd, "enc %d", &v) == 1) {
        int idle = enc_pending == 0;
        enc_pending += v;
        if (idle) avr_cycle_timer_register_usec(avr, 100, enc_tick, NULL);
        printf("ok\n");
    } else if (strncmp(cmd, "glitch", 6) == 0) { /* both phases at once: an edge missed */
        enc_a ^= 1;
        enc_b ^= 1;
        enc_set(enc_pin_a, enc_a);
        enc_set(enc_pin_b, enc_b);
        printf("ok\n");
    } else if (strncmp(cmd, "pulse", 5) == 0) {
        printf("pulse %.1f period %.1f frames %u\n", servo_pulse_us(),
               (double)servo_period * 1e6 / avr->frequency, servo_frames);
    } else if (strncmp(cmd, "lag", 3) == 0) { /* the worst since last asked */
        printf("lag %.0f\n", worst_lag_us);
        worst_lag_us = 0;
    } else if (strncmp(cmd, "stats", 5) == 0) {
        printf("stats sim_us %llu host_ns %llu cycles %llu rangings %u srf02_addr 0x%02x pc 0x%x twi %u last 0x%08x\n",
               (unsigned long long)sim_us(), (unsigned long long)mono_ns(), (unsigned long long)avr->cycle, srf.rangings, srf.addr, (unsigned)avr->pc, srf.msgs, (unsigned)srf.last_msg);
    } else if (sscanf(cmd, "peek %x", (unsigned *)&v) == 1) {
        printf("peek %02x %02x %02x %02x\n", avr->data[v], avr->data[v + 1], avr->data[v + 2], avr->data[v + 3]);
    } else if (strncmp(cmd, "trig", 4) == 0) {
        printf("trig %u %.3f %.3f\n", trig_edges, trig_rise ? board_us_at(trig_rise) : -1.0,
               trig_fall ? board_us_at(trig_fall) : -1.0);
    } else if (sscanf(cmd, "ain %d %d", &v, &mv) == 2 && v >= 1 && v <= 7) { /* ADC1..7, mV */
        avr_raise_irq(avr_io_getirq(avr, AVR_IOCTL_ADC_GETIRQ, ADC_IRQ_ADC0 + v), (uint32_t)mv);
        printf("ok\n");
    } else if (strncmp(cmd, "adc", 3) == 0) {
        unsigned n = adc_n < ADC_LOG ? adc_n : ADC_LOG;
        printf("adc %u", n);
        for (unsigned i = adc_n - n; i < adc_n; i++) printf(" %.3f", board_us_at(adc_starts[i % ADC_LOG]));
        printf("\n");
    } else if (strncmp(cmd, "stack", 5) == 0) {
        printf("stack 0x%04x 0x%x\n", sp_min, (unsigned)sp_min_pc);
    } else if (sscanf(cmd, "cut %d", &v) == 1 && v > 0) {
        eeprom_cut(v);
        printf("ok\n");
    } else if (strncmp(cmd, "quit", 4) == 0) {
        power_off();
    } else {
        printf("error unknown command: %s\n", cmd);
    }
    fflush(stdout);
}

static void poll_stdin(void) {
    char c;
    ssize_t r;
    while ((r = read(0, &c, 1)) == 1) {
        if (c == '\n') {
            line[line_n] = 0;
            command(line);
            line_n = 0;
        } else if (line_n < sizeof line - 1) {
            line[line_n++] = c;
        }
    }
    if (r == 0) power_off(); /* stdin closed: the test is gone */
}

static void pace(void) {
    /* simulated µs must not run ahead of host µs * (1 + skew) */
    double host_us = (double)(mono_ns() - start_ns) / 1000.0 * (1.0 + skew);
    double ahead = (double)sim_us() - host_us;
    if (-ahead > worst_lag_us) worst_lag_us = -ahead;
    if (ahead > 50) usleep((useconds_t)(ahead / (1.0 + skew)));
}

int main(int argc, char **argv) {
    const char *elf = NULL, *mcu = "atmega328p";
    for (int i = 1; i < argc; i++) {
        if (!strcmp(argv[i], "--mcu") && i + 1 < argc) mcu = argv[++i];
        else if (!strcmp(argv[i], "--skew-ppm") && i + 1 < argc) skew = atof(argv[++i]) * 1e-6;
        else if (!strcmp(argv[i], "--eeprom") && i + 1 < argc) eeprom_file = argv[++i];
        else if (!strcmp(argv[i], "--rover")) rover = 1;
        else elf = argv[i];
    }
    if (!elf) {
        fprintf(stderr, "usage: rig_sim FIRMWARE.elf [--mcu atmega328p] [--skew-ppm P]\n");
        return 2;
    }
    elf_firmware_t f;
    memset(&f, 0, sizeof f);
    if (elf_read_firmware(elf, &f) != 0) {
        fprintf(stderr, "rig_sim: cannot read %s\n", elf);
        return 1;
    }
    strncpy(f.mmcu, mcu, sizeof f.mmcu - 1);
    f.frequency = 16000000;
    f.vcc = f.avcc = f.aref = 5000;
    avr = avr_make_mcu_by_name(mcu);
    if (!avr) {
        fprintf(stderr, "rig_sim: simavr has no %s\n", mcu);
        return 1;
    }
    avr_init(avr);
    avr_load_firmware(avr, &f);
    avr->log = 0;
    eeprom_open(avr, eeprom_file);
    if (strcmp(mcu, "atmega328p") != 0) { /* Mega/Leonardo: INT0/1 = PD0/PD1, OC1A = PB5 */
        enc_pin_a = 0;
        enc_pin_b = 1;
        servo_pin = 5;
        trig_pin = 4;
    }
    uart_pty_init(avr, &uart);
    uart_pty_connect(&uart, strcmp(mcu, "atmega32u4") ? '0' : '1');
    static const char *names[] = {"8<srf02.in"};
    srf.irq = avr_alloc_irq(&avr->irq_pool, 0, 1, names);
    avr_irq_register_notify(srf.irq, srf_hook, NULL);
    avr_connect_irq(avr_io_getirq(avr, AVR_IOCTL_TWI_GETIRQ(0), TWI_IRQ_OUTPUT), srf.irq);
    avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_IOPORT_GETIRQ(servo_port), servo_pin),
                            servo_hook, NULL);
    if (rover) rover_init(avr, board_us_at);
    avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_ADC_GETIRQ, ADC_IRQ_OUT_TRIGGER), adc_hook,
                            NULL);
    enc_set(enc_pin_a, enc_a);
    enc_set(enc_pin_b, enc_b);
    sharp_update();
    fcntl(0, F_SETFL, fcntl(0, F_GETFL) | O_NONBLOCK);
    printf("PTY %s\n", uart.port[0].slavename);
    fflush(stdout);
    start_ns = mono_ns();
    for (unsigned long n = 0;; n++) {
        int state = avr_run(avr);
        if (state == cpu_Done || state == cpu_Crashed) {
            fprintf(stderr, "rig_sim: the AVR stopped (state %d)\n", state);
            return 1;
        }
        watch();
        if (cut_left > 0) eeprom_watch();
        if ((n & 1023) == 0) {
            pace();
            poll_stdin();
        }
    }
}
