/* A GPS receiver on the firmware's second UART (gps.c): NMEA at 9600 baud into USART1 (RX1),
 * one byte per 10 bit times, each simulated second RMC (with its date) then GGA, after a PPS
 * edge 100 ms wide (on its pin, when it has one: the Mega's D2, PE4, INT4); every `bad`-th
 * sentence with a wrong checksum.  UTC starts at 12:35:19 on 23 March 1994 (NMEA's own
 * example) and the date turns at midnight.
 * Control lines: gps bad N | gps fix Q | gps utc S (the next second is S s since 1970) |
 *   gps: "gps SENT PPS_US UTC", the newest PPS edge in the board's µs and its UTC second */
#ifndef RIG_GPS_H
#define RIG_GPS_H
#include "rig.h"

void gps_add(char pps_port, int pps_bit); /* pps_port 0: no PPS pin */
int gps_command(const char *line);
#endif
