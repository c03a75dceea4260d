/* J2A framing on the board (spec Part 1): the byte-at-a-time frame parser and the frame encoder.
 * The same state machine as the Python runtime's board/wire.py (FrameParser, encode_frame). */
#ifndef J2A_WIRE_H
#define J2A_WIRE_H
#include <stdint.h>

#define SOF 0x12
#define SOS 0xED
#define ESC 0x7D

/* Events from frame_parser_feed (EV_NONE: keep feeding). */
enum { EV_NONE = 0, EV_REQUEST, EV_CUT, EV_CHECKSUM, EV_ESCAPE };

typedef struct {
    uint8_t buf[255];
    uint8_t state, esc, seq, op, n, i, csum;
    uint8_t has_seq; /* an event's seq is valid (the cut came after the seq byte) */
    uint16_t errors, frames;
} frame_parser_t;

void frame_parser_init(frame_parser_t *p);
uint8_t frame_parser_in_frame(const frame_parser_t *p);
/* One byte in, at most one event out (p->seq, p->op, p->buf[0..n) describe it). */
uint8_t frame_parser_feed(frame_parser_t *p, uint8_t b);
/* Inter-byte silence: drop the frame; EV_CUT if one was open, else EV_NONE. */
uint8_t frame_parser_abort(frame_parser_t *p);

/* Encoder: an output sink receives the escaped bytes. */
typedef void (*byte_sink_t)(uint8_t b);
uint8_t frame_checksum(uint8_t seq, uint8_t op, const uint8_t *payload, uint8_t n);
void encode_frame(byte_sink_t out, uint8_t start, uint8_t seq, uint8_t op,
                  const uint8_t *payload, uint8_t n);
/* A frame whose payload is head[0..hn) then the flash strings a and b (0: none): the board's
 * log lines (log.c), whose texts never leave flash. */
void encode_frame_P(byte_sink_t out, uint8_t start, uint8_t seq, uint8_t op, const uint8_t *head,
                    uint8_t hn, const char *a, uint8_t an, const char *b, uint8_t bn);
/* Worst-case encoded size of a frame with n payload bytes (every byte escaped). */
#define FRAME_MAX(n) (1u + 2u * (3u + (n) + 1u))
#endif
