/* The EEPROM across power cycles, and power cuts (eeprom.c), for rig_sim. */
#ifndef RIG_EEPROM_H
#define RIG_EEPROM_H
#include "sim_avr.h"

/* bytes still to be written before the power goes (-1: never); a variable, not a call, as
 * rig_sim looks at it after every instruction */
extern int cut_left;

/* file: where the contents live across power cycles (NULL: nowhere); read now when it exists */
void eeprom_open(avr_t *avr, const char *file);
void eeprom_cut(int n); /* the power goes after the next n bytes written */
void eeprom_watch(void); /* while a cut is armed: after every instruction */
void power_off(void);   /* the contents saved, the rig stopped */
#endif
