/* Quadrature encoders at the firmware's pins (encoder.c): Gray-code edges on phases A and B,
 * one edge every 100 µs of simulated time until the steps asked for are made.
 * Control lines (K: the encoder, in the order they were added; 0 when left out):
 *   enc [K] STEPS: STEPS edges (x4 counts), forward (> 0) or back
 *   glitch [K]: both phases at once (an edge missed)
 *   encpos [K]: "encpos K COUNT US", the edges made so far (forward minus back) and the newest
 *          one's time in the board's µs (-1: none yet) */
#ifndef RIG_ENCODER_H
#define RIG_ENCODER_H
#include "rig.h"

#define ENCODERS 8

/* an encoder with phase A on a_port/a_bit and B on b_port/b_bit (both high at rest); its index */
int encoder_add(char a_port, int a_bit, char b_port, int b_bit);
int encoder_count(void);
void encoder_steps(int k, long steps); /* queued after the ones still pending */
int encoder_command(const char *line);
#endif
