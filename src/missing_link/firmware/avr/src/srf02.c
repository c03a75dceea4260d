/* The SRF02 sonar on TWI (drivers.h): the MicroPython driver's behaviour (board/drivers/, Python), which says
 * what the datasheet asks; the comments here say only what differs on this hardware. */
#include "drivers.h"
#include "hal.h"
#include "log.h"
#include "schedule.h"
#include "twi.h"

/* ---- SRF02 on TWI (100 kHz master, every wait bounded) ---------------------------------------- */
static transducer_t *srf02_t;
static uint8_t srf02_addr, srf02_min;
static schedule_t srf02_s;
static uint32_t srf02_ping_us, srf02_check_us; /* board µs (hal.h) */
static uint8_t srf02_ranging;
uint16_t srf02_timeouts, srf02_bus_errors;

void srf02_init(transducer_t *t, uint8_t address, uint16_t rate_hz, uint8_t min_range_cm) {
    srf02_t = t;
    srf02_addr = address;
    srf02_min = min_range_cm;
    srf02_s.period_us = 1000000UL / rate_hz;
    if (srf02_s.period_us < 65000UL) srf02_s.period_us = 65000UL; /* a ranging takes 65 ms */
    twi_init();
}

void srf02_set(float rate_hz, uint16_t min_range_cm) {
    sched_rate(&srf02_s, rate_hz < 15.38f ? rate_hz : 15.38f); /* a ranging takes 65 ms */
    srf02_min = (uint8_t)(min_range_cm > 255 ? 255 : min_range_cm);
}

void srf02_align(uint8_t aligned, float phase) { sched_align(&srf02_s, aligned, phase); }

void srf02_poll(uint32_t now) {
    if (!srf02_t) return;
    if (!srf02_ranging) {
        if (!sched_due(&srf02_s, &now)) return;
        const uint8_t cmd = 0x51; /* range in cm */
        sched_wait(&srf02_s, &now); /* the command starts on the instant */
        uint8_t st = twi_transfer(srf02_addr, 0, &cmd, 1, 0, 0);
        if (st != 0) { /* between rangings it answers: no acknowledge is an absent part */
            log_fault_P(srf02_t->tid, st == 1 ? FAULT_NO_ANSWER : FAULT_BUS, 0);
            srf02_bus_errors++;
            record_na(srf02_t, 0, now);
            return;
        }
        srf02_ping_us = clock_now();
        srf02_check_us = srf02_ping_us + 65000UL;
        srf02_ranging = 1;
        return;
    }
    if (!clock_due(now, srf02_check_us)) return;
    uint8_t rev = 0xFF;
    uint8_t st = twi_transfer(srf02_addr, 0, 0, 0, &rev, 1);
    if (st == 2) {
        log_fault_P(srf02_t->tid, FAULT_BUS, 0);
        srf02_bus_errors++;
    }
    if (st != 0 || rev == 0xFF) { /* still ranging */
        if (now - srf02_ping_us >= 100000UL) {
            log_fault_P(srf02_t->tid, FAULT_TIMEOUT, 0);
            srf02_timeouts++;
            srf02_ranging = 0;
            record_na(srf02_t, 0, now);
        } else {
            srf02_check_us = now + 5000UL;
        }
        return;
    }
    srf02_ranging = 0;
    uint8_t r[2];
    if (twi_transfer(srf02_addr, 2, 0, 0, r, 2) != 0) {
        log_fault_P(srf02_t->tid, FAULT_BUS, 0);
        srf02_bus_errors++;
        record_na(srf02_t, 0, now);
        return;
    }
    uint16_t cm = (uint16_t)((r[0] << 8) | r[1]);
    if (cm == 0 || cm < srf02_min) record_na(srf02_t, 0, now);
    else record(srf02_t, 0, cm, srf02_ping_us + (uint32_t)cm * 583UL / 20UL); /* + half flight */
}

