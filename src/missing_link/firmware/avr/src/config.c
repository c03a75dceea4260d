/* Run-time configuration on AVR: the same functions and bytes as board/config.py (Python).
 *
 * Theory of operation
 * -------------------
 * The keys, their kinds, limits and defaults are generated from the board file (board_gen.c),
 * with the key table's text in flash (a2jConfigKeys, served like the descriptors).  What runs
 * is board_config_values[] (raw bits: int32, or float); a set is checked whole first (every
 * value against its kind and limits, then the combination: board_config_check), then applied
 * key by key (board_config_apply), so it is all or nothing.  Error texts are Python's:
 * "NAME: expected LIMITS", "NAME: read-only", the driver's "TRANSDUCER: reason".
 *
 * Saving: the record of board/config.py ([MLC][version][schema crc][count][values][crc16]) in
 * one of two EEPROM slots, after a sequence byte.  A save writes the slot that does not hold the
 * newest valid record, sequence first, then the record; the newest slot whose crc matches wins
 * at boot.  A power cut in the middle of a save leaves a slot whose crc does not match: the
 * other one, the old configuration, is used.  A record of another board file (schema crc) is
 * ignored.  Reset with erase spoils both slots' magic.
 */
#include "config.h"

#include <avr/eeprom.h>
#include <avr/pgmspace.h>
#include <string.h>

#include "log.h"

#define EE_BASE 16 /* (0..3: the boot counter of clock.epoch, main.c) */
#define VERSION 1
#if defined(__AVR_ATmega2560__)
#define CONFIG_MAX 64 /* keys (8 KiB of RAM); the generator refuses more (avrconfig.MAX_KEYS) */
#else
#define CONFIG_MAX 32 /* keys (the stack's room on 2 KiB); the generator refuses more */
#endif
#define REC_LEN(n) (9u + 4u * (n))
#define SLOT_LEN(n) (1u + REC_LEN(n))
enum { ST_SAVED = 1, ST_LOADED = 2, ST_DIRTY = 4 };

uint8_t config_state;

uint16_t crc16(const uint8_t *data, uint16_t n, uint16_t crc) {
    /* CRC-16/CCITT-FALSE (start 0xFFFF), as board/config.py */
    while (n--) {
        crc ^= (uint16_t)(*data++) << 8;
        for (uint8_t k = 0; k < 8; k++) crc = crc & 0x8000 ? (uint16_t)((crc << 1) ^ 0x1021) : (uint16_t)(crc << 1);
    }
    return crc;
}

static void key_of(uint8_t i, config_key_t *k) {
    config_row_t r;
    memcpy_P(&r, &board_config_keys[i], sizeof r);
    k->kind = r.kind & (uint8_t)~CONFIG_RO;
    k->read_only = r.kind >> 7;
    k->def = r.def;
    memcpy_P(&k->lo, &board_config_limits[2 * r.limits], 8);
}

/* ---- the key table's text: field f (0 name, 3 limits) of key i's line, appended to out --- */
static uint8_t append_field(uint8_t i, uint8_t f, uint8_t *out, uint8_t at) {
    const blob_t *b = &board_config_keys_blob;
    uint16_t len = b->len(), p = 0;
    uint8_t line = 0, field = 0;
    while (p < len && b->at(p) != '\n') p++; /* "config/1" */
    p++;
    for (; p < len && line <= i; p++) {
        uint8_t c = b->at(p);
        if (c == '\n') {
            line++;
            field = 0;
        } else if (c == ';') {
            field++;
        } else if (line == i && field == f && at < 200) {
            out[at++] = c;
        }
    }
    return at;
}

#define say runtime_say
static const char no_key[] PROGMEM = "no key index";

/* 0 if raw is a value key i allows, else the reply text's length (in out) */
static uint8_t refuse(uint8_t i, uint32_t raw, uint8_t *out) {
    config_key_t k;
    key_of(i, &k);
    uint8_t at = append_field(i, 0, out, 0);
    if (k.read_only) return say(out, at, PSTR(": read-only"));
    uint8_t ok;
    if (k.kind == KIND_FLOAT) {
        float v, lo, hi;
        memcpy(&v, &raw, 4);
        memcpy(&lo, &k.lo, 4);
        memcpy(&hi, &k.hi, 4);
        if (v != v) return say(out, at, PSTR(": not a number"));
        ok = lo <= v && v <= hi;
    } else if (k.kind == KIND_BOOL) {
        if (raw > 1) return say(out, at, PSTR(": expected 0 or 1"));
        ok = 1;
    } else if (k.kind == KIND_ENUM) {
        if (raw > k.hi) return append_field(i, 3, out, say(out, at, PSTR(": expected one of ")));
        ok = 1;
    } else {
        ok = (int32_t)k.lo <= (int32_t)raw && (int32_t)raw <= (int32_t)k.hi;
    }
    return ok ? 0 : append_field(i, 3, out, say(out, at, PSTR(": expected ")));
}

/* ---- all or nothing --------------------------------------------------------------------------- */
static uint8_t commit(const uint32_t *cand, uint8_t *out) {
    /* 0 when cand runs now, else the reply text's length: nothing changed */
    const char *why = board_config_check(cand);
    if (why) return say(out, 0, why);
    for (uint8_t i = 0; i < board_config_count; i++) {
        if (cand[i] != board_config_values[i]) {
            board_config_values[i] = cand[i];
            board_config_apply(cand, i);
        }
    }
    return 0;
}

/* ---- EEPROM slots ----------------------------------------------------------------------------- */
static uint16_t slot_at(uint8_t s) { return EE_BASE + (uint16_t)s * SLOT_LEN(board_config_count); }

static uint8_t ee(uint16_t a) { return eeprom_read_byte((const uint8_t *)a); }

/* 1 if slot s holds a valid record of this board file */
static uint8_t slot_valid(uint8_t s) {
    uint16_t a = slot_at(s) + 1, n = REC_LEN(board_config_count), crc = 0xFFFF;
    uint8_t head[7];
    for (uint8_t i = 0; i < 7; i++) head[i] = ee(a + i);
    if (head[0] != 'M' || head[1] != 'L' || head[2] != 'C' || head[3] != VERSION) return 0;
    if ((uint16_t)(head[4] | (head[5] << 8)) != board_config_schema_crc) return 0;
    if (head[6] != board_config_count) return 0;
    for (uint16_t i = 0; i + 2 < n; i++) {
        uint8_t b = ee(a + i);
        crc = crc16(&b, 1, crc);
    }
    return crc == (uint16_t)(ee(a + n - 2) | (ee(a + n - 1) << 8));
}

/* the slot with the newest valid record, or -1 */
static int8_t newest_slot(void) {
    uint8_t v0 = slot_valid(0), v1 = slot_valid(1);
    if (v0 && v1) return (uint8_t)(ee(slot_at(1)) - ee(slot_at(0))) < 128 ? 1 : 0;
    return v1 ? 1 : v0 ? 0 : -1;
}

static uint32_t saved_value(uint8_t s, uint8_t i) {
    uint32_t v;
    eeprom_read_block(&v, (const void *)(slot_at(s) + 8 + 4 * i), 4);
    return v;
}

static void save(void) {
    int8_t now = newest_slot();
    uint8_t s = now == 0 ? 1 : 0, seq = now < 0 ? 0 : (uint8_t)(ee(slot_at((uint8_t)now)) + 1);
    uint8_t head[8] = {seq, 'M', 'L', 'C', VERSION, (uint8_t)board_config_schema_crc,
                       (uint8_t)(board_config_schema_crc >> 8), board_config_count};
    uint16_t a = slot_at(s), crc = crc16(head + 1, 7, 0xFFFF);
    eeprom_update_block(head, (void *)a, 8);
    for (uint8_t i = 0; i < board_config_count; i++) {
        eeprom_update_block(&board_config_values[i], (void *)(a + 8 + 4 * i), 4);
        crc = crc16((const uint8_t *)&board_config_values[i], 4, crc);
    }
    eeprom_update_word((uint16_t *)(a + 8 + 4 * board_config_count), crc);
    config_state |= ST_SAVED;
}

static uint8_t dirty(void) {
    int8_t s = newest_slot();
    config_key_t k;
    for (uint8_t i = 0; i < board_config_count; i++) {
        key_of(i, &k);
        uint32_t ref = s >= 0 ? saved_value((uint8_t)s, i) : k.def;
        if (ref != board_config_values[i]) return 1;
    }
    return 0;
}

void config_boot(void) {
    config_key_t k;
    uint32_t cand[CONFIG_MAX];
    for (uint8_t i = 0; i < board_config_count; i++) {
        key_of(i, &k);
        board_config_values[i] = cand[i] = k.def;
    }
    int8_t s = newest_slot();
    if (s < 0) return;
    config_state |= ST_SAVED;
    uint8_t scratch[64];
    for (uint8_t i = 0; i < board_config_count; i++) {
        uint32_t v = saved_value((uint8_t)s, i);
        if (!refuse(i, v, scratch)) cand[i] = v;
    }
    if (commit(cand, scratch) == 0) config_state |= ST_LOADED;
    else {
        runtime_debug("saved configuration refused;");
        log_line_P(LOG_WARN, LOG_BOARD, PSTR("saved configuration refused"), 0);
    }
}

/* ---- the J2A functions ------------------------------------------------------------------------ */
uint8_t config_get(const uint8_t *in, uint8_t n, uint8_t *out, uint8_t *out_n) {
    uint8_t first = n ? in[0] : 0;
    if (first > board_config_count) {
        *out_n = (uint8_t)(say(out, 0, no_key));
        return 0xFF;
    }
    out[0] = first;
    out[1] = board_config_count;
    out[2] = (uint8_t)(config_state | (dirty() ? ST_DIRTY : 0));
    uint8_t k = 3;
    for (uint8_t i = first; i < board_config_count && k + 4 <= 255; i++, k += 4)
        memcpy(out + k, &board_config_values[i], 4);
    *out_n = k;
    return 0;
}

uint8_t config_set(const uint8_t *in, uint8_t n, uint8_t *out, uint8_t *out_n) {
    uint32_t cand[CONFIG_MAX];
    *out_n = 0;
    if (n == 0 || (n - 1) % 5) {
        *out_n = say(out, 0, PSTR("expects [flags] + ([index][4-byte value])*"));
        return 0xFF;
    }
    memcpy(cand, board_config_values, 4u * board_config_count);
    uint8_t flags = in[0];
    for (uint8_t p = 1; p < n; p += 5) {
        uint8_t i = in[p];
        uint32_t raw;
        memcpy(&raw, in + p + 1, 4);
        if (i >= board_config_count) {
            *out_n = say(out, 0, no_key);
            return 0xFF;
        }
        uint8_t why = refuse(i, raw, out);
        if (why) {
            *out_n = why;
            return 0xFF;
        }
        cand[i] = raw;
    }
    uint8_t why = commit(cand, out);
    if (why) {
        *out_n = why;
        return 0xFF;
    }
    if (flags & 1) save();
    return 0;
}

uint8_t config_reset(const uint8_t *in, uint8_t n, uint8_t *out, uint8_t *out_n) {
    uint32_t cand[CONFIG_MAX];
    config_key_t k;
    *out_n = 0;
    for (uint8_t i = 0; i < board_config_count; i++) {
        key_of(i, &k);
        cand[i] = k.read_only ? board_config_values[i] : k.def;
    }
    uint8_t why = commit(cand, out);
    if (why) {
        *out_n = why;
        return 0xFF;
    }
    if (n && (in[0] & 1)) {
        eeprom_update_byte((uint8_t *)(slot_at(0) + 1), 0xFF); /* no magic: no record */
        eeprom_update_byte((uint8_t *)(slot_at(1) + 1), 0xFF);
        config_state &= (uint8_t)~ST_SAVED;
    }
    return 0;
}
