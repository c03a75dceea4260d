/* The golden-vector board of docs/protocol.md (Golden vectors) in C: the original (Part 1)
 * function table of the 2014 firmware - the built-ins, getTime, syncTime, bigBlob - so the
 * vectors' exact bytes can be checked against this runtime on AVR machine code
 * (tests/test_avr.py). */
#include <avr/pgmspace.h>
#include <string.h>

#include "hal.h"
#include "builtins.h"

transducer_t board_transducers[1];
const uint8_t board_transducer_count = 0;

static const char props[] PROGMEM = "board.name\0golden\0board.model\0avr-golden\0clock.epoch\0";
static uint16_t props_len(void) { return sizeof props - 1 + strlen(clock_epoch) + 1; }
static uint8_t props_at(uint16_t i) {
    if (i < sizeof props - 1) return pgm_read_byte(props + i);
    i -= sizeof props - 1;
    return i < strlen(clock_epoch) ? (uint8_t)clock_epoch[i] : 0;
}
const blob_t board_properties_blob = {props_len, props_at};
static uint16_t none_len(void) { return 0; }
static uint8_t none_at(uint16_t i) { (void)i; return 0; }
const blob_t board_transds_blob = {none_len, none_at};

static uint8_t get_time(const uint8_t *in, uint8_t n, uint8_t *out, uint8_t *out_n) {
    (void)in;
    (void)n;
    uint64_t t = board_clock();
    for (uint8_t i = 0; i < 8; i++) out[i] = (uint8_t)(t >> (8 * i));
    *out_n = 8;
    return 0;
}

static uint8_t sync_time(const uint8_t *in, uint8_t n, uint8_t *out, uint8_t *out_n) {
    (void)in;
    (void)n;
    (void)out;
    *out_n = 0;
    return 0;
}

/* bigBlob: (i * 7 + 3) & 0xFF for i < 1000, as the MicroPython golden board */
static uint16_t big_len(void) { return 1000; }
static uint8_t big_at(uint16_t i) { return (uint8_t)(i * 7 + 3); }
static const blob_t big_blob = {big_len, big_at};

static const char n_get_time[] PROGMEM = "getTime";
static const char n_sync_time[] PROGMEM = "syncTime";
static const char n_big_blob[] PROGMEM = "bigBlob";

const function_t board_functions[] PROGMEM = {
    {n_get_mapping, KIND_PLAIN, get_mapping, 0},
    {n_many, KIND_PLAIN, 0, 0},
    {n_get_properties, KIND_BLOB, 0, &board_properties_blob},
    {n_debug, KIND_PLAIN, get_debug, 0},
    {n_echo, KIND_PLAIN, echo, 0},
    {n_echo_many, KIND_ECHO_MANY, 0, 0},
    {n_get_time, KIND_PLAIN, get_time, 0},
    {n_sync_time, KIND_PLAIN, sync_time, 0},
    {n_big_blob, KIND_BLOB, 0, &big_blob},
};
const uint8_t board_function_count = 9;

void board_setup(void) {}
void board_poll(uint32_t now) { (void)now; }
