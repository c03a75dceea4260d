/* The EEPROM across power cycles, and power cuts, for rig_sim (rig_sim.c's --eeprom FILE and its
 * `cut N` command): the contents are read from FILE at power-up and written back when the rig is
 * powered off; a cut stops the rig at once after the next N bytes the firmware writes. */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "avr_eeprom.h"
#include "eeprom.h"

static const char *eeprom_file;
static uint8_t *eeprom;
static uint32_t eeprom_size;
static uint8_t eeprom_seen[8192];
int cut_left = -1; /* bytes still to be written before the power goes (-1: never) */

void eeprom_open(avr_t *avr, const char *file) {
    eeprom_file = file;
    avr_eeprom_desc_t d = {.ee = NULL, .offset = 0, .size = 0};
    avr_ioctl(avr, AVR_IOCTL_EEPROM_GET, &d); /* (simavr 1.6 answers -1 even when it worked) */
    if (!d.ee) return;
    eeprom = d.ee;
    eeprom_size = avr->e2end + 1;
    if (eeprom_size > sizeof eeprom_seen) eeprom_size = sizeof eeprom_seen;
    FILE *f = eeprom_file ? fopen(eeprom_file, "rb") : NULL;
    if (f) {
        if (fread(eeprom, 1, eeprom_size, f) != eeprom_size) fprintf(stderr, "rig_sim: short EEPROM file\n");
        fclose(f);
    }
    memcpy(eeprom_seen, eeprom, eeprom_size);
}

void eeprom_cut(int n) {
    memcpy(eeprom_seen, eeprom, eeprom_size);
    cut_left = n;
}

static void eeprom_save(void) {
    if (!eeprom || !eeprom_file) return;
    FILE *f = fopen(eeprom_file, "wb");
    if (!f || fwrite(eeprom, 1, eeprom_size, f) != eeprom_size) perror("rig_sim: EEPROM file");
    if (f) fclose(f);
}

void power_off(void) {
    eeprom_save();
    exit(0);
}

/* while a cut is armed: after every instruction, the bytes that changed since */
void eeprom_watch(void) {
    for (uint32_t a = 0; a < eeprom_size; a++) {
        if (eeprom[a] != eeprom_seen[a]) {
            eeprom_seen[a] = eeprom[a];
            if (--cut_left == 0) {
                eeprom_save();
                printf("CUT\n");
                fflush(stdout);
                _exit(0);
            }
        }
    }
}
