/* missing-link AVR board: J2A over the UART, the board file's transducers (board_gen.c). */
#include <avr/eeprom.h>
#include <avr/interrupt.h>
#include <avr/io.h>

#include "failsafe.h"
#include "hal.h"
#include "identity.h"
#include "runtime.h"
#include "timing.h"

#define FEED_PER_TURN 32 /* the UART's receive ring (hal.c) */

#ifndef BOARD_BAUD
#define BOARD_BAUD 115200UL
#endif

/* clock.epoch differs at every boot: a boot counter in EEPROM (no RNG on an AVR) */
static void epoch_init(void) {
    uint32_t boots = eeprom_read_dword((uint32_t *)0) + 1;
    eeprom_write_dword((uint32_t *)0, boots);
    for (uint8_t i = 0; i < 8; i++) {
        uint8_t d = (boots >> (28 - 4 * i)) & 15;
        clock_epoch[i] = (char)(d < 10 ? '0' + d : 'a' + d - 10);
    }
    clock_epoch[8] = 0;
}

#ifdef J2A_PROFILE
/* bench/bench_avr.py reads these (simavr): Timer1 ticks (0.5 µs = 8 cycles) spent in
 * runtime_feed per received byte, and in writing sample SIFs (runtime.c). */
volatile uint32_t prof_feed_ticks, prof_feed_bytes;
static uint16_t ticks_since(uint16_t t0) {
    uint16_t t1 = TCNT1;
    return t1 >= t0 ? t1 - t0 : (uint16_t)(t1 + 40000u - t0);
}
#endif

int main(void) {
    board_clock_init();
    link_init(BOARD_BAUD);
    runtime_init();
    epoch_init();
    identity_init(); /* board.id: the stamp into the EEPROM at the first boot (identity.c) */
    board_setup();
    sei();
    for (;;) {
        uint8_t b = 0;
        uint32_t rx_us;
        /* At most a ring's worth of bytes a turn: a stream whose error replies outrun it (a
         * 7-byte F2 for every 2 bytes of cut frames) must not keep the failsafe from its turn. */
        for (uint8_t k = 0; k < FEED_PER_TURN && link_read(&b, &rx_us); k++) {
#ifdef J2A_PROFILE
            uint16_t t0 = TCNT1;
            runtime_feed(b, rx_us);
            prof_feed_ticks += ticks_since(t0);
            prof_feed_bytes++;
#else
            runtime_feed(b, rx_us);
#endif
        }
        uint32_t now = clock_now();
        failsafe_poll(now); /* first: a silent host's timed calls are dropped, not run */
        timing_poll(now);   /* then the timed calls that are due (timing.c) */
        runtime_poll();
    }
}
