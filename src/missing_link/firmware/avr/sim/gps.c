/* A GPS receiver on the firmware's second UART (gps.h). */
#include "gps.h"

#include <stdio.h>
#include <string.h>

#include "avr_uart.h"
#include "sim_time.h"

static avr_irq_t *rx1, *pps_irq;
static int present;
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
    if (pps_irq) avr_raise_irq(pps_irq, 0);
    return 0;
}

static avr_cycle_count_t gps_second(avr_t *a, avr_cycle_count_t when, void *param) {
    (void)a;
    (void)param;
    gps_utc++;
    pps_cycle = when;
    if (pps_irq) avr_raise_irq(pps_irq, 1);
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

void gps_add(char pps_port, int pps_bit) {
    present = 1;
    rx1 = avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('1'), UART_IRQ_INPUT);
    /* (PPS starts low without being raised: a "low" raised while INT4 is still in its power-up
     * low-level mode starts simavr 1.6's level poll, which outlives the switch to rising edge
     * and then raises INT4 for ever) */
    if (pps_port) pps_irq = rig_pin_irq(pps_port, pps_bit);
    avr_cycle_timer_register_usec(avr, 1000000, gps_second, NULL);
}

int gps_command(const char *cmd) {
    int v;
    long long utc;
    if (!present || strncmp(cmd, "gps", 3) != 0) return 0;
    if (sscanf(cmd, "gps bad %d", &v) == 1) {
        gps_bad = v;
        printf("ok\n");
    } else if (sscanf(cmd, "gps fix %d", &v) == 1) {
        gps_fix = v;
        printf("ok\n");
    } else if (sscanf(cmd, "gps utc %lld", &utc) == 1) {
        gps_utc = utc - 1;
        printf("ok\n");
    } else if (!strcmp(cmd, "gps")) {
        printf("gps %u %.3f %lld\n", gps_sent, pps_cycle ? board_us_at(pps_cycle) : -1.0, gps_utc);
    } else {
        return 0;
    }
    return 1;
}
