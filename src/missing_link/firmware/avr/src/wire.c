/* J2A frame parser and encoder for the board.
 *
 * Theory of operation
 * -------------------
 * The board gets its input one byte at a time from the UART and has 2 KiB of RAM, so the parser
 * is a byte-at-a-time state machine with one fixed 255-byte payload buffer:
 *
 *   HUNT --0x12--> SEQ -> OP -> LEN -> DATA (len bytes) -> CSUM --> request (or error)
 *   HUNT --0xED--> IGNORE: a board never acts on SIF frames (spec 1.1); we keep hunting.
 *
 * ESC (0x7D) sets a flag and the next byte is taken +1; a result that is not one of the three
 * specials is a bad escape.  A raw 0x12/0xED inside a frame means the frame was cut: the parser
 * reports it (with the seq if it had arrived) and starts again at that marker.  The runtime
 * answers errors with error frames (0xF2/0xF3/0xF4), as the original firmware.  The same
 * machine, state for state, as the Python runtime's FrameParser (board/wire.py).
 */
#include "wire.h"

#include <avr/pgmspace.h>

enum { HUNT = 0, S_SEQ, S_OP, S_LEN, S_DATA, S_CSUM, IGNORE };

void frame_parser_init(frame_parser_t *p) {
    p->state = HUNT;
    p->esc = 0;
    p->errors = p->frames = 0;
}

uint8_t frame_parser_in_frame(const frame_parser_t *p) {
    return p->state != HUNT && p->state != IGNORE;
}

uint8_t frame_parser_abort(frame_parser_t *p) {
    uint8_t st = p->state;
    p->state = HUNT;
    p->esc = 0;
    if (st == HUNT || st == IGNORE) return EV_NONE;
    p->errors++;
    p->has_seq = st > S_SEQ;
    return EV_CUT;
}

uint8_t frame_parser_feed(frame_parser_t *p, uint8_t b) {
    uint8_t st = p->state;
    if (b == SOF || b == SOS) {
        uint8_t ev = EV_NONE;
        if (st != HUNT && st != IGNORE) {
            p->errors++;
            p->has_seq = st > S_SEQ;
            ev = EV_CUT;
        }
        p->esc = 0;
        p->state = b == SOF ? S_SEQ : IGNORE;
        return ev;
    }
    if (st == HUNT || st == IGNORE) return EV_NONE;
    if (p->esc) {
        p->esc = 0;
        b++;
        if (b != SOF && b != SOS && b != ESC) {
            p->errors++;
            p->has_seq = st > S_SEQ;
            p->state = HUNT;
            return EV_ESCAPE;
        }
    } else if (b == ESC) {
        p->esc = 1;
        return EV_NONE;
    }
    switch (st) {
    case S_SEQ:
        p->seq = b;
        p->csum = b;
        p->state = S_OP;
        break;
    case S_OP:
        p->op = b;
        p->csum ^= (uint8_t)(b + 11);
        p->state = S_LEN;
        break;
    case S_LEN:
        p->n = b;
        p->i = 0;
        p->csum ^= (uint8_t)(b + 97);
        p->state = b ? S_DATA : S_CSUM;
        break;
    case S_DATA:
        p->buf[p->i++] = b;
        p->csum ^= b;
        if (p->i == p->n) p->state = S_CSUM;
        break;
    default: /* S_CSUM */
        p->state = HUNT;
        p->has_seq = 1;
        if (b != p->csum) {
            p->errors++;
            return EV_CHECKSUM;
        }
        p->frames++;
        return EV_REQUEST;
    }
    return EV_NONE;
}

uint8_t frame_checksum(uint8_t seq, uint8_t op, const uint8_t *payload, uint8_t n) {
    uint8_t c = seq ^ (uint8_t)(op + 11) ^ (uint8_t)(n + 97);
    for (uint8_t i = 0; i < n; i++) c ^= payload[i];
    return c;
}

static void put_escaped(byte_sink_t out, uint8_t b) {
    if (b == SOF || b == SOS || b == ESC) {
        out(ESC);
        out((uint8_t)(b - 1));
    } else {
        out(b);
    }
}

static uint8_t put_flash(byte_sink_t out, const char *s, uint8_t n) {
    uint8_t c = 0;
    for (uint8_t i = 0; i < n; i++) {
        uint8_t b = pgm_read_byte(s + i);
        put_escaped(out, b);
        c ^= b;
    }
    return c;
}

void encode_frame_P(byte_sink_t out, uint8_t start, uint8_t seq, uint8_t op, const uint8_t *head,
                    uint8_t hn, const char *a, uint8_t an, const char *b, uint8_t bn) {
    uint8_t n = (uint8_t)(hn + an + bn);
    uint8_t c = seq ^ (uint8_t)(op + 11) ^ (uint8_t)(n + 97);
    out(start);
    put_escaped(out, seq);
    put_escaped(out, op);
    put_escaped(out, n);
    for (uint8_t i = 0; i < hn; i++) {
        put_escaped(out, head[i]);
        c ^= head[i];
    }
    c ^= put_flash(out, a, an);
    c ^= put_flash(out, b, bn);
    put_escaped(out, c);
}

void encode_frame(byte_sink_t out, uint8_t start, uint8_t seq, uint8_t op,
                  const uint8_t *payload, uint8_t n) {
    out(start);
    put_escaped(out, seq);
    put_escaped(out, op);
    put_escaped(out, n);
    for (uint8_t i = 0; i < n; i++) put_escaped(out, payload[i]);
    put_escaped(out, frame_checksum(seq, op, payload, n));
}
