/* See link.h. */
#include <poll.h>
#include <stdio.h>
#include <string.h>

#include "avr_uart.h"
#include "link.h"
#include "rig.h"

DEFINE_FIFO(uint8_t, uart_pty_fifo); /* (simavr's accessors for the FIFO its header declares) */

/* room kept in the FIFO for the bytes a stretch of avr_run() may send before the next look */
#define LINK_HOLD_BYTES 384

static uart_pty_t *link_pty;
static unsigned long long sent, dropped, held;
static int holding;

/* runs before uart_pty's own hook (simavr calls an IRQ's hooks newest first) */
static void byte_hook(struct avr_irq_t *irq, uint32_t value, void *param) {
    (void)irq, (void)value, (void)param;
    sent++;
    if (uart_pty_fifo_isfull(&link_pty->pty.in)) dropped++;
}

void link_watch(uart_pty_t *pty, char which) {
    link_pty = pty;
    avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ(which), UART_IRQ_OUTPUT),
                            byte_hook, NULL);
}

/* the pty takes bytes now: its thread is only late (else the host's buffer is full).  A pty
 * whose host end closed says POLLOUT with POLLHUP while its writes fail: no room. */
static int pty_has_room(void) {
    struct pollfd p = {.fd = link_pty->pty.s, .events = POLLOUT};
    return poll(&p, 1, 0) == 1 && (p.revents & (POLLOUT | POLLHUP | POLLERR)) == POLLOUT;
}

int link_backed_up(void) {
    int hold = uart_pty_fifo_get_read_size(&link_pty->pty.in) > LINK_HOLD_BYTES && pty_has_room();
    if (hold && !holding) held++;
    holding = hold;
    return hold;
}

int link_command(const char *line) {
    if (strcmp(line, "uart") != 0) return 0;
    printf("uart sent %llu dropped %llu held %llu\n", sent, dropped, held);
    return 1;
}
