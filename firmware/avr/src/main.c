/* missing-link AVR board: J2A over the UART, the board file's transducers (board_gen.c). */
#include <avr/eeprom.h>
#include <avr/interrupt.h>

#include "hal.h"
#include "runtime.h"

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

int main(void) {
    board_clock_init();
    link_init(BOARD_BAUD);
    runtime_init();
    epoch_init();
    board_setup();
    sei();
    for (;;) {
        uint8_t b;
        uint64_t rx_us;
        while (link_read(&b, &rx_us)) runtime_feed(b, rx_us);
        runtime_poll();
    }
}
