/* The rover's parts at the Mega's pins (examples/boards/rover-mega.py's wiring):
 *   motors   Timer0's OC0A (D13, PB7) and OC0B (D4, PG5) with direction pins D22 (PA0) and D23
 *            (PA1): the duty as the datasheet's fast PWM makes it from the registers,
 *            (OCR0x + 1) / 256 while COM0x1 is set, else the pin's PORT level (0 or 1)
 *   stepper  step D26 (PA4), dir D27 (PA5), enable D28 (PA6, active low): rising step edges
 *            counted while enabled, forward while dir is high
 *   HC-SR04  trig D24 (PA2), echo D53 (PB0): at the trigger pulse's falling edge the echo rises
 *            450 µs later for the round trip at 343.4 m/s (20 degC), or 38 ms with nothing in range
 *   GPS      NMEA at 9600 baud into USART1 (RX1), one byte per 10 bit times, each simulated
 *            second RMC (with its date) then GGA after a PPS edge on D2 (PE4, INT4) 100 ms
 *            wide; every `bad`-th sentence with a wrong checksum.  UTC starts at 12:35:19 on
 *            23 March 1994 (NMEA's own example) and the date turns at midnight.
 * Control lines: motor | stepper | hcsr04 MM (0: nothing in range) | gps bad N | gps fix Q |
 *   gps utc S (the next second is S s since 1970) | gps: "gps SENT PPS_US UTC", the newest PPS
 *   edge in the board's us and its UTC second */
#include "rover.h"

#include <stdio.h>
#include <string.h>

#include "avr_ioport.h"
#include "avr_uart.h"
#include "sim_time.h"

static avr_t *avr;
static double (*rig_board_us)(avr_cycle_count_t cycle); /* rig_sim.c's clock */
enum { PORTA = 0x22, PORTB = 0x25, PORTG = 0x34, TCCR0A = 0x44, OCR0A = 0x47, OCR0B = 0x48 };

/* ---- motors ---- */
static double duty(int b) {
    uint8_t com = avr->data[TCCR0A] >> (b ? 4 : 6) & 3;
    if (com == 2) return (avr->data[b ? OCR0B : OCR0A] + 1) / 256.0;
    return b ? (avr->data[PORTG] >> 5 & 1) : (avr->data[PORTB] >> 7 & 1);
}

/* ---- stepper ---- */
static long step_pos, step_count, step_ignored;

static void step_hook(struct avr_irq_t *irq, uint32_t value, void *param) {
    (void)irq;
    (void)param;
    if (!value) return;
    if (avr->data[PORTA] & 0x40) { /* enable high: the driver is off */
        step_ignored++;
        return;
    }
    step_count++;
    step_pos += (avr->data[PORTA] & 0x20) ? 1 : -1;
}

/* ---- HC-SR04 ---- */
static int sonar_mm = 1000;
static unsigned sonar_rangings;
static avr_irq_t *echo_irq;

static avr_cycle_count_t echo_fall(avr_t *a, avr_cycle_count_t when, void *param) {
    (void)a;
    (void)when;
    (void)param;
    avr_raise_irq(echo_irq, 0);
    return 0;
}

static avr_cycle_count_t echo_rise(avr_t *a, avr_cycle_count_t when, void *param) {
    (void)a;
    (void)when;
    (void)param;
    avr_raise_irq(echo_irq, 1);
    double us = sonar_mm > 0 ? 2.0 * sonar_mm / 1000.0 / 343.42 * 1e6 : 38000.0;
    avr_cycle_timer_register_usec(avr, (uint32_t)(us + 0.5), echo_fall, NULL);
    return 0;
}

static void trig_hook(struct avr_irq_t *irq, uint32_t value, void *param) {
    (void)irq;
    (void)param;
    static uint32_t last;
    if (last && !value) { /* the trigger pulse ended: the burst, then the echo */
        sonar_rangings++;
        avr_cycle_timer_register_usec(avr, 450, echo_rise, NULL);
    }
    last = value;
}

/* ---- GPS ---- */
static avr_irq_t *rx1, *pps_irq;
static char gps_out[256];
static size_t gps_len, gps_pos;
static int gps_bad, gps_fix = 1;
static unsigned gps_sent;
static long long gps_utc = 764426119 - 1; /* the current second's UTC, s since 1970 */
static avr_cycle_count_t pps_cycle;

/* days since 1970-01-01 -> the civil date (Gregorian), written as ddmmyy */
static void nmea_date(long long days, char *out, size_t size) {
    long long z = days + 719468, era = z / 146097, doe = z - era * 146097;
    long long yoe = (doe - doe / 1460 + doe / 36524 - doe / 146096) / 365;
    long long doy = doe - (365 * yoe + yoe / 4 - yoe / 100), mp = (5 * doy + 2) / 153;
    long long d = doy - (153 * mp + 2) / 5 + 1, m = mp < 10 ? mp + 3 : mp - 9;
    long long y = yoe + era * 400 + (m <= 2);
    snprintf(out, size, "%02lld%02lld%02lld", d, m, y % 100);
}

static void nmea(const char *body) {
    unsigned c = 0;
    for (const char *p = body; *p; p++) c ^= (unsigned char)*p;
    gps_sent++;
    if (gps_bad && gps_sent % gps_bad == 0) c ^= 0x5A;
    gps_len += snprintf(gps_out + gps_len, sizeof gps_out - gps_len, "$%s*%02X\r\n", body, c);
}

static avr_cycle_count_t gps_byte(avr_t *a, avr_cycle_count_t when, void *param) {
    (void)a;
    (void)param;
    if (gps_pos >= gps_len) return 0;
    avr_raise_irq(rx1, (uint8_t)gps_out[gps_pos++]);
    return when + avr_usec_to_cycles(avr, 1042); /* 10 bits at 9600 baud */
}

static avr_cycle_count_t pps_low(avr_t *a, avr_cycle_count_t when, void *param) {
    (void)a;
    (void)when;
    (void)param;
    avr_raise_irq(pps_irq, 0);
    return 0;
}

static avr_cycle_count_t gps_second(avr_t *a, avr_cycle_count_t when, void *param) {
    (void)a;
    (void)param;
    gps_utc++;
    pps_cycle = when;
    avr_raise_irq(pps_irq, 1);
    avr_cycle_timer_register_usec(avr, 100000, pps_low, NULL);
    long t = (long)(gps_utc % 86400);
    char hms[16], date[40], body[128];
    snprintf(hms, sizeof hms, "%02ld%02ld%02ld.00", t / 3600, (t / 60) % 60, t % 60);
    nmea_date(gps_utc / 86400, date, sizeof date);
    gps_len = gps_pos = 0;
    if (gps_fix) {
        snprintf(body, sizeof body, "GPRMC,%s,A,4807.0380,N,01131.0000,E,022.4,084.4,%s,003.1,W", hms, date);
        nmea(body);
        snprintf(body, sizeof body, "GPGGA,%s,4807.0380,N,01131.0000,E,%d,08,0.9,545.4,M,46.9,M,,", hms, gps_fix);
    } else {
        snprintf(body, sizeof body, "GPRMC,%s,V,,,,,022.4,084.4,%s,003.1,W", hms, date);
        nmea(body);
        snprintf(body, sizeof body, "GPGGA,%s,,,,,0,08,0.9,,M,46.9,M,,", hms);
    }
    nmea(body);
    avr_cycle_timer_register_usec(avr, 5000, gps_byte, NULL); /* the sentences follow the PPS */
    return when + avr_usec_to_cycles(avr, 1000000);
}

void rover_init(avr_t *a, double (*board_us)(avr_cycle_count_t cycle)) {
    rig_board_us = board_us;
    avr = a;
    avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_IOPORT_GETIRQ('A'), 4), step_hook, NULL);
    avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_IOPORT_GETIRQ('A'), 2), trig_hook, NULL);
    echo_irq = avr_io_getirq(avr, AVR_IOCTL_IOPORT_GETIRQ('B'), 0);
    avr_raise_irq(echo_irq, 0);
    rx1 = avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('1'), UART_IRQ_INPUT);
    /* (PPS starts low without being raised: a "low" raised while INT4 is still in its power-up
     * low-level mode starts simavr 1.6's level poll, which outlives the switch to rising edge
     * and then raises INT4 for ever) */
    pps_irq = avr_io_getirq(avr, AVR_IOCTL_IOPORT_GETIRQ('E'), 4);
    avr_cycle_timer_register_usec(avr, 1000000, gps_second, NULL);
}

int rover_command(const char *cmd) {
    int v;
    long long utc;
    if (!strncmp(cmd, "motor", 5)) {
        printf("motor %.4f %d %.4f %d\n", duty(0), avr->data[PORTA] & 1, duty(1),
               avr->data[PORTA] >> 1 & 1);
    } else if (!strncmp(cmd, "stepper", 7)) {
        printf("stepper %ld %d %ld %ld\n", step_pos, !(avr->data[PORTA] & 0x40), step_count,
               step_ignored);
    } else if (sscanf(cmd, "hcsr04 %d", &v) == 1) {
        sonar_mm = v;
        printf("ok\n");
    } else if (sscanf(cmd, "gps bad %d", &v) == 1) {
        gps_bad = v;
        printf("ok\n");
    } else if (sscanf(cmd, "gps fix %d", &v) == 1) {
        gps_fix = v;
        printf("ok\n");
    } else if (sscanf(cmd, "gps utc %lld", &utc) == 1) {
        gps_utc = utc - 1;
        printf("ok\n");
    } else if (!strncmp(cmd, "gps", 3)) {
        printf("gps %u %.3f %lld\n", gps_sent, pps_cycle ? rig_board_us(pps_cycle) : -1.0, gps_utc);
    } else {
        return 0;
    }
    return 1;
}
