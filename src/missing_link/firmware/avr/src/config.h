/* Run-time configuration on AVR: the same functions, bytes and record as the Python runtime
 * (board/config.py; docs/configuration.md), the record kept in EEPROM. */
#ifndef J2A_CONFIG_H
#define J2A_CONFIG_H
#include <stdint.h>

#include "features.h"
#include "runtime.h"

enum { KIND_BOOL = 0, KIND_INT, KIND_FLOAT, KIND_ENUM };

/* One key: its kind, limits (raw bits: int32, or float for KIND_FLOAT; an enum's choices are
 * 0..hi) and default (raw bits). */
typedef struct {
    uint8_t kind;
    uint8_t read_only;
    uint32_t lo, hi, def;
} config_key_t;
/* ... as it is in flash: the kind (CONFIG_RO: read-only), its limits' pair in
 * board_config_limits (keys share them), the default */
#define CONFIG_RO 0x80
typedef struct {
    uint8_t kind, limits;
    uint32_t def;
} config_row_t;

/* Generated from the board file (board_gen.c): */
extern const config_row_t board_config_keys[];        /* PROGMEM */
extern const uint32_t board_config_limits[];          /* PROGMEM: (lo, hi) pairs */
extern const uint8_t board_config_count;
extern const blob_t board_config_keys_blob;           /* "config/1\n" + one line per key */
extern const uint16_t board_config_schema_crc;        /* crc16 of that blob */
extern uint32_t board_config_values[];                /* what runs now (raw bits) */
void board_config_apply(const uint32_t *v, uint8_t i); /* key i's value to its driver */
const char *board_config_check(const uint32_t *v);    /* a combination's problem (PROGMEM) */

/* The J2A functions (a2jConfigGet, a2jConfigSet, a2jConfigReset) and the boot-time load. */
uint8_t config_get(const uint8_t *in, uint8_t n, uint8_t *out, uint8_t *out_n);
uint8_t config_set(const uint8_t *in, uint8_t n, uint8_t *out, uint8_t *out_n);
uint8_t config_reset(const uint8_t *in, uint8_t n, uint8_t *out, uint8_t *out_n);
void config_boot(void);
uint16_t crc16(const uint8_t *data, uint16_t n, uint16_t crc);
extern uint8_t config_state;
#endif
