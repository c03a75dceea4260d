/* Who this board is: board.id, a serial kept in the EEPROM's last 32 bytes (identity.c). */
#ifndef J2A_IDENTITY_H
#define J2A_IDENTITY_H
#include <stdint.h>

/* At boot, before anything reads the properties: the id the image was stamped with goes into
 * the EEPROM when the EEPROM has none, or when the stamp says so (flash --id). */
void identity_init(void);
/* board.id's length (0: none) and its byte at i < identity_len() */
uint8_t identity_len(void);
uint8_t identity_at(uint8_t i);

#endif
