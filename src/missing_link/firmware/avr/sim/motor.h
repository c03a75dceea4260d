/* DC motors behind H-bridges at the firmware's Timer0 outputs (motor.c), and wheels they turn.
 * A motor's drive is what its bridge's inputs make of it, as the datasheet's fast PWM makes
 * them from the registers: on OC0A/OC0B (Uno D6/D5, Mega D13/D4) a duty of (OCR0x + 1) / 256
 * while COM0x1 is set, else the pin's PORT level (0 or 1); a PWM/DIR bridge turns back while its
 * direction pin is high, an IN1/IN2 bridge (both outputs) drives as IN1 - IN2 (both high: brake).
 * A wheel is a motor turning an encoder (encoder.c): its speed follows the drive as a first-order
 * lag (time constant WHEEL_TAU_S) up to its top speed at full drive, and the encoder's edges
 * follow its angle.  The model's state is the seam for a world (rig.h): `wheel K off` leaves
 * the encoder to whatever sets it (enc K STEPS).
 * Control lines (K: in the order they were added):
 *   motor: "motor D0 R0 D1 R1 ...", each motor's drive (0..1) and whether it turns back (1)
 *   wheels: "wheels K REV REV_S ...", each wheel's angle (turns) and speed (turns/s)
 *   wheel K on / off: the model drives the encoder, or does not */
#ifndef RIG_MOTOR_H
#define RIG_MOTOR_H
#include "rig.h"

void motor_init(const char *mcu); /* where Timer0's outputs are */
/* a motor on output `out` (0: OC0A, 1: OC0B; 2: both, IN1/IN2) with its direction pin */
int motor_add(int out, char dir_port, int dir_bit);
/* motor `motor` turns encoder `encoder`: `cpr` edges a turn, `top` turns/s at full drive */
int wheel_add(int motor, int encoder, double cpr, double top);
int motor_command(const char *line);
#endif
