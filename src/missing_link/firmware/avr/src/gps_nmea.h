/* A GPS receiver's NMEA 0183 on USART1 (gps_nmea.c; board/drivers/gps_nmea.py). */
#ifndef J2A_GPS_NMEA_H
#define J2A_GPS_NMEA_H
#include <stdint.h>

#include "runtime.h"

void gps_init(transducer_t *t, uint32_t baud, uint8_t pps);
void gps_poll(uint32_t now);
extern uint16_t gps_sentences, gps_checksum_errors, gps_overruns;
#endif
