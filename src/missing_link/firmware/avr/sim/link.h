/* The board's link as the host's serial port sees it.  simavr's uart_pty bridges the AVR's UART
 * to a pseudo-terminal: the AVR's bytes wait in a 512-byte FIFO for a thread of its own to write
 * them to the pty, and a byte that finds the FIFO full is dropped.  A real board's bytes wait in
 * the host's serial buffers instead (kilobytes) and none is lost while they have room; so when
 * that thread runs late (a busy machine) while the AVR runs on, the AVR is held until the FIFO
 * drains (link_backed_up): its time stands still meanwhile and pace() catches up after, as after
 * any other stretch the machine held the rig back.  When the pty itself is full (the host reads
 * nothing: no host, or one that stopped), the AVR runs on and its bytes are dropped, as a real
 * board's are once the host's buffers are full.
 *   uart: "uart sent N dropped D held H", the bytes the AVR's UART sent, those dropped, and how
 *         many times the AVR was held for the FIFO to drain */
#ifndef RIG_LINK_H
#define RIG_LINK_H
#include "parts/uart_pty.h"

/* watch uart `which` ('0', '1') of a connected uart_pty (after uart_pty_connect) */
void link_watch(uart_pty_t *pty, char which);
/* 1 while the AVR must wait for the FIFO to drain */
int link_backed_up(void);
int link_command(const char *line);
#endif
