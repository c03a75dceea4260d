/* board.id on AVR: a serial written at flash time, kept in the EEPROM (board/identity.py says
 * what the property is on every runtime; docs/hardware.md, "Identity").
 *
 * The Arduino bootloaders write flash only (the Uno's optiboot has no EEPROM writes), so the id
 * travels in the image: `missing-link flash` (deploy/avrstamp.py) stamps it into `identity_stamp`
 * below, and this code puts it into the EEPROM at the first boot.  After that the EEPROM is
 * what counts: a re-flash of the program (stamped with a fresh default id) leaves it as it is,
 * unless the stamp is forced (`flash --id ID`).
 *
 * The record, the last 32 bytes of the EEPROM (config.c's slots start at 16, main.c's boot
 * counter is at 0):  "MLID" | n (1..25) | n bytes of text, zeros after | forced | check
 * where check = 0xA5 ^ every byte before it.  The stamp is that record as the EEPROM will hold
 * it; "forced" (1: flash --id) makes the board take it over a valid record.  A record that
 * does not check (never written, or cut by a power loss while it was written) is no id: the
 * stamp is written again. */
#include <avr/eeprom.h>
#include <avr/io.h>
#include <avr/pgmspace.h>

#include "identity.h"

#define ID_LEN 32
#define ID_AT (E2END + 1 - ID_LEN)
#define ID_MAX 25
#define MAGIC 0x44494C4DUL /* "MLID", little-endian */

/* The stamp.  Until stamped, this placeholder (deploy/avrstamp.py finds it in the ELF and
 * writes the record over it: keep it as it is). */
const char identity_stamp[ID_LEN] PROGMEM = "@@missing-link-id-placeholder@@";

static uint8_t id_len; /* of the record in the EEPROM; 0: none */

static uint8_t ee(uint8_t i) { return eeprom_read_byte((const uint8_t *)(ID_AT + i)); }

/* the length of the valid record in the EEPROM, or 0 */
static uint8_t record_len(void) {
    uint8_t check = 0xA5, n = ee(4);
    for (uint8_t i = 0; i < ID_LEN - 1; i++) check ^= ee(i);
    if (eeprom_read_dword((const uint32_t *)ID_AT) != MAGIC || check != ee(ID_LEN - 1)) return 0;
    return n >= 1 && n <= ID_MAX ? n : 0;
}

void identity_init(void) {
    uint8_t have = record_len();
    if (pgm_read_dword(identity_stamp) == MAGIC && (have == 0 || pgm_read_byte(identity_stamp + 30))) {
        for (uint8_t i = 0; i < ID_LEN; i++) /* (only the bytes that change are written) */
            eeprom_update_byte((uint8_t *)(ID_AT + i), pgm_read_byte(identity_stamp + i));
        have = record_len();
    }
    id_len = have;
}

uint8_t identity_len(void) { return id_len; }

uint8_t identity_at(uint8_t i) { return ee(5 + i); }
