/* A GPS receiver's NMEA 0183: the same sentences, checks, channels and stamps as
 * board/drivers/gps_nmea.py (Python), which says what they are (channels 8 and 9: the UTC day
 * and ms of day of the PPS edge a whole second's fix is stamped at).  On the Mega's USART1 (RX1
 * D19, TX1 D18; the Uno's only UART is the J2A link), bytes go into a ring by interrupt, a '$'
 * stamped with Timer1's count as it arrives; the PPS edge on INT4 (D2) likewise, at the
 * interrupt's entry: 1.875 us after the edge in simavr, and later by whatever interrupt was
 * running then (Timer1's overflow, the link's UART: up to 3.875 us measured with the host
 * calling a2jEcho without a pause, tests/test_avr_rover.py).  The main loop parses whole
 * lines, in integer maths. */
#include "gps_nmea.h"

#include <avr/interrupt.h>
#include <avr/io.h>
#include <string.h>
#include <util/atomic.h>

#include "hal.h"
#include "log.h"

#if defined(UDR1)
#define RING 128 /* 133 ms of 9600 baud */
#define NA_I32 0x80000000UL
#define MAX_SENTENCE 82
#define PPS_VALID_US 1100000UL

static transducer_t *gt;
static volatile uint8_t ring[RING], head, tail;
static volatile uint32_t dollar_w[4], pps_w;
static volatile uint16_t dollar_t[4], pps_t;
static volatile uint8_t dollar_head, pps_seen;
static uint8_t dollar_tail;
static char line[MAX_SENTENCE + 2];
static uint8_t line_n, in_line;
static uint32_t line_us;
static char rmc_time[12];
static int32_t rmc_speed, rmc_course; /* NA_I32 when none */
static int32_t rmc_day = -1, rmc_tod;  /* the last valid RMC's date (days since 1970), time (ms) */
uint16_t gps_sentences, gps_checksum_errors, gps_overruns;

ISR(USART1_RX_vect) {
    uint8_t b = UDR1;
    uint8_t next = (uint8_t)((head + 1) % RING);
    if (next == tail) {
        gps_overruns++;
        return;
    }
    if (b == '$') {
        uint16_t t = TCNT1;
        dollar_w[dollar_head & 3] = clock_wraps_at(t);
        dollar_t[dollar_head & 3] = t;
        dollar_head++;
    }
    ring[head] = b;
    head = next;
}

ISR(INT4_vect) {
    uint16_t t = TCNT1;
    pps_w = clock_wraps_at(t);
    pps_t = t;
    pps_seen = 1;
}

void gps_init(transducer_t *t, uint32_t baud, uint8_t pps) {
    gt = t;
    UCSR1A = _BV(U2X1);
    UBRR1 = (uint16_t)((F_CPU / 8 + baud / 2) / baud - 1);
    UCSR1C = _BV(UCSZ11) | _BV(UCSZ10);
    UCSR1B = _BV(RXEN1) | _BV(RXCIE1);
    if (pps) {
        DDRE &= (uint8_t)~_BV(PE4);
        EICRB |= _BV(ISC41) | _BV(ISC40); /* rising edge */
        EIMSK |= _BV(INT4);
    }
    rmc_time[0] = 0;
}

static uint8_t hex(char c) {
    if (c >= '0' && c <= '9') return (uint8_t)(c - '0');
    if (c >= 'A' && c <= 'F') return (uint8_t)(c - 'A' + 10);
    if (c >= 'a' && c <= 'f') return (uint8_t)(c - 'a' + 10);
    return 0xFF;
}

/* the n-th comma-separated field of the body (after the sentence type), its length in *len */
static const char *field(const char *s, uint8_t n, uint8_t *len) {
    while (n && *s) {
        if (*s++ == ',') n--;
    }
    const char *e = s;
    while (*e && *e != ',') e++;
    *len = (uint8_t)(e - s);
    return s;
}

static int32_t digits(const char *s, uint8_t n) {
    int32_t v = 0;
    for (uint8_t i = 0; i < n; i++) v = v * 10 + (s[i] - '0');
    return v;
}

/* "12.34" * scale (a power of ten), rounded; NA_I32 when empty */
static int32_t decimal(const char *s, uint8_t n, int32_t scale) {
    if (!n) return (int32_t)NA_I32;
    uint8_t neg = *s == '-';
    if (neg) {
        s++;
        n--;
    }
    uint8_t i = 0;
    int32_t whole = 0;
    while (i < n && s[i] != '.') whole = whole * 10 + (s[i++] - '0');
    int32_t frac = 0, f = scale * 10;
    if (i < n) i++;
    for (int32_t d = 1; d < f; d *= 10) frac = frac * 10 + (i < n ? s[i++] - '0' : 0);
    int32_t v = (whole * scale * 10 + frac + 5) / 10;
    return neg ? -v : v;
}

/* ddmm.mmmm / dddmm.mmmm and a hemisphere -> 1e-7 degree */
static int32_t coord(const char *s, uint8_t n, char hemi, uint8_t deg_digits) {
    uint8_t dot = 0;
    while (dot < n && s[dot] != '.') dot++;
    if (dot >= n || dot < deg_digits) return (int32_t)NA_I32;
    int32_t deg = digits(s, deg_digits);
    int32_t minutes = digits(s + deg_digits, (uint8_t)(dot - deg_digits)); /* * 1e5 below */
    int32_t frac = 0;
    for (uint8_t i = 0; i < 5; i++) frac = frac * 10 + (dot + 1 + i < n ? s[dot + 1 + i] - '0' : 0);
    int32_t e7 = deg * 10000000L + (minutes * 100000L + frac) * 10 / 6;
    return hemi == 'S' || hemi == 'W' ? -e7 : e7;
}

/* n digits at s, or -1 when one is not a digit */
static int32_t number(const char *s, uint8_t n) {
    for (uint8_t i = 0; i < n; i++)
        if (s[i] < '0' || s[i] > '9') return -1;
    return digits(s, n);
}

/* "hhmmss[.sss]" -> ms since midnight; -1 when it is none (or a leap second: POSIX has none) */
static int32_t time_of_day_ms(const char *s, uint8_t n) {
    if (n < 6 || (n > 6 && s[6] != '.')) return -1;
    int32_t h = number(s, 2), m = number(s + 2, 2), sec = number(s + 4, 2), ms = 0;
    if (h < 0 || m < 0 || sec < 0 || h > 23 || m > 59 || sec > 59) return -1;
    for (uint8_t i = 7; i < 10; i++) ms = ms * 10 + (i < n && s[i] >= '0' && s[i] <= '9' ? s[i] - '0' : 0);
    return ((h * 60 + m) * 60 + sec) * 1000L + ms;
}

/* RMC's "ddmmyy" -> days since 1970-01-01 (years 80-99: 19yy, else 20yy); -1 when none */
static int32_t date_days(const char *s, uint8_t n) {
    if (n != 6) return -1;
    int32_t d = number(s, 2), m = number(s + 2, 2), y = number(s + 4, 2);
    if (d < 1 || d > 31 || m < 1 || m > 12 || y < 0) return -1;
    y += y >= 80 ? 1900 : 2000;
    if (m <= 2) y--; /* (the days before each March: February's leap day is the year's last) */
    int32_t doy = (153 * (m + (m > 2 ? -3 : 9)) + 2) / 5 + d - 1;
    return y * 365 + y / 4 - y / 100 + y / 400 + doy - 719468;
}

/* v[8], v[9]: the UTC day and ms of day of the GGA's time (tm), the day from the last valid
 * RMC's date: the same second's or the one before's (gps_nmea.py's _utc) */
static void utc(const char *tm, uint8_t n, int32_t *v) {
    int32_t tod = time_of_day_ms(tm, n);
    if (rmc_day < 0 || tod < 0) return;
    int32_t day = rmc_day, since = tod - rmc_tod;
    if (since < 0) { /* (midnight between the RMC and this GGA) */
        day++;
        since += 86400000L;
    }
    if (since > 1000) {
        rmc_day = -1; /* a date is never carried further */
        return;
    }
    v[8] = day;
    v[9] = tod;
}

static void gga(const char *b, uint32_t at_us) {
    uint8_t n, hn;
    const char *q = field(b, 6, &n);
    int32_t quality = n ? digits(q, n) : 0;
    int32_t v[10];
    const char *lat = field(b, 2, &n), *h = field(b, 3, &hn);
    v[0] = quality ? coord(lat, n, hn ? *h : 'N', 2) : (int32_t)NA_I32;
    const char *lon = field(b, 4, &n);
    h = field(b, 5, &hn);
    v[1] = quality ? coord(lon, n, hn ? *h : 'E', 3) : (int32_t)NA_I32;
    const char *alt = field(b, 9, &n);
    v[2] = quality ? decimal(alt, n, 1000) : (int32_t)NA_I32;
    v[3] = quality;
    const char *sats = field(b, 7, &n);
    v[4] = n ? digits(sats, n) : 0;
    const char *hdop = field(b, 8, &n);
    v[5] = decimal(hdop, n, 100);
    const char *tm = field(b, 1, &n);
    v[6] = v[7] = v[8] = v[9] = (int32_t)NA_I32;
    if (n < sizeof rmc_time && !strncmp(tm, rmc_time, n) && rmc_time[n] == 0) {
        v[6] = rmc_speed;
        v[7] = rmc_course;
    }
    uint32_t stamp = at_us;
    uint32_t w;
    uint16_t t;
    uint8_t seen;
    ATOMIC_BLOCK(ATOMIC_RESTORESTATE) { /* (the next edge's interrupt may come meanwhile) */
        w = pps_w;
        t = pps_t;
        seen = pps_seen;
    }
    if (seen) {
        uint32_t pps = clock_at(w, t);
        if (at_us - pps < PPS_VALID_US) { /* (and not before it: that wraps far) */
            uint32_t frac_us = 0;
            uint8_t i = 0;
            while (i < n && tm[i] != '.') i++;
            for (uint8_t d = 0; d < 6; d++) frac_us = frac_us * 10 + (i + 1 + d < n ? tm[i + 1 + d] - '0' : 0);
            stamp = pps + frac_us;
            if (!frac_us) utc(tm, n, v); /* the fix of the edge's own second: its UTC */
        }
    }
    for (uint8_t ch = 0; ch < 10; ch++) {
        if ((uint32_t)v[ch] == NA_I32) record_na(gt, ch, stamp);
        else record(gt, ch, (uint32_t)v[ch], stamp);
    }
}

static void rmc(const char *b) {
    uint8_t n, sn;
    const char *tm = field(b, 1, &n);
    const char *status = field(b, 2, &sn);
    uint8_t valid = sn && *status == 'A';
    if (n >= sizeof rmc_time) n = sizeof rmc_time - 1;
    memcpy(rmc_time, tm, n);
    rmc_time[n] = 0;
    const char *sp = field(b, 7, &n);
    int32_t knots = decimal(sp, n, 1000);
    rmc_speed = valid && (uint32_t)knots != NA_I32 ? (int32_t)((int64_t)knots * 1852 / 3600) : (int32_t)NA_I32;
    const char *co = field(b, 8, &n);
    rmc_course = valid ? decimal(co, n, 100) : (int32_t)NA_I32;
    const char *date = field(b, 9, &n);
    rmc_day = valid ? date_days(date, n) : -1;
    rmc_tod = time_of_day_ms(tm, (uint8_t)strlen(rmc_time));
    if (rmc_tod < 0) rmc_day = -1;
}

static void bad_sentence(void) { /* dropped, counted; the first said (log.c) */
    gps_checksum_errors++;
    log_fault_P(gt->tid, FAULT_CHECKSUM, 0);
}

static void sentence(uint32_t at_us) {
    /* line: "$...*hh" without the "\r\n" */
    char *star = strchr(line, '*');
    if (!star || star + 3 != line + line_n) {
        bad_sentence();
        return;
    }
    uint8_t hi = hex(star[1]), lo = hex(star[2]), c = 0;
    for (char *p = line + 1; p < star; p++) c ^= (uint8_t)*p;
    if (hi > 15 || lo > 15 || c != (uint8_t)(hi << 4 | lo)) {
        bad_sentence();
        return;
    }
    *star = 0;
    gps_sentences++;
    const char *body = line + 1; /* "GPGGA,..." */
    if (star - body < 5) return;
    if (!strncmp(body + 2, "RMC,", 4)) rmc(body);
    else if (!strncmp(body + 2, "GGA,", 4)) gga(body, at_us);
}

void gps_poll(uint32_t now) {
    (void)now;
    while (tail != head) {
        uint8_t b = ring[tail];
        tail = (uint8_t)((tail + 1) % RING);
        if (b == '$') {
            uint8_t k = dollar_tail++ & 3;
            line_us = clock_at(dollar_w[k], dollar_t[k]);
            line[0] = '$';
            line_n = 1;
            in_line = 1;
        } else if (!in_line) {
            continue;
        } else if (b == '\n') {
            if (line_n && line[line_n - 1] == '\r') line_n--;
            line[line_n] = 0;
            in_line = 0;
            sentence(line_us);
        } else if (line_n < MAX_SENTENCE + 1) {
            line[line_n++] = (char)b;
        } else {
            in_line = 0;
            bad_sentence(); /* not NMEA: dropped */
        }
    }
}
#else
void gps_init(transducer_t *t, uint32_t baud, uint8_t pps) {
    (void)t;
    (void)baud;
    (void)pps;
}
void gps_poll(uint32_t now) { (void)now; }
uint16_t gps_sentences, gps_checksum_errors, gps_overruns;
#endif
