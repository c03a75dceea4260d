/* Board clock and UART link on an ATmega (328P, 2560, 32U4) at 16 MHz.
 *
 * The clock: Timer1 in fast PWM mode 14 (TOP = ICR1) at 2 MHz (prescaler 8) wraps every 20 ms;
 * its overflow interrupt counts wraps, so the clock is wraps * 20000 + TCNT1 / 2 µs, 64 bit
 * (hal.h: what runs on its low 32 bits).
 * The same timer drives the servo's 50 Hz PWM on OC1A, so one timer serves both.  A read with
 * interrupts off checks the pending overflow flag, so a read just after the wrap (before the
 * interrupt ran) is not 20 ms early.  Where there is a Timer2 (not on the 32U4) it starts in the
 * same tick at the same 2 MHz, free-running: its count is the clock's ticks mod 256 ever after,
 * which is what lets the trigger (trigger.c) put a compare match on a board tick without reading it.
 *
 * The UART: received bytes go into a ring by interrupt, each stamped with the raw timer and the
 * low byte of the wrap count (cheap enough for 1 Mbaud, no 64-bit maths in the interrupt, 3 bytes
 * of RAM per entry; a byte is read within 5 s, so the low byte is enough); bytes to send go
 * through a TX ring drained by the data-register-empty interrupt.
 *
 * Interrupts are held off only to take a snapshot of the counts (tens of cycles), never for the
 * sums: the trigger's compare interrupt (trigger.c) must run within its step's lead. */
#include "hal.h"

#include <avr/interrupt.h>
#include <avr/io.h>
#include <util/atomic.h>

#if F_CPU != 16000000UL
#error "the board clock assumes a 16 MHz crystal (Uno, Nano, Mega, Leonardo)"
#endif

#define TIMER_TOP 39999u /* 40000 ticks of 0.5 µs = 20 ms */

static volatile uint32_t clock_wraps;
/* clock_wraps * CLOCK_PERIOD_US, kept by the interrupt (a multiply per read would cost more than
 * the read): its low and high words, so that the 32-bit clock reads the low one alone */
static volatile union {
    uint64_t us;
    struct {
        uint32_t lo, hi;
    } w;
} clock_base;

ISR(TIMER1_OVF_vect) {
    clock_wraps++;
    uint32_t lo = clock_base.w.lo + CLOCK_PERIOD_US;
    clock_base.w.lo = lo;
    if (lo < CLOCK_PERIOD_US) clock_base.w.hi++;
}

void board_clock_init(void) {
#if defined(TCCR2B)
    GTCCR = _BV(TSM) | _BV(PSRASY) | _BV(PSRSYNC); /* both prescalers held in reset ... */
#endif
    ICR1 = TIMER_TOP; /* TOP first: the timer must never run with TOP = 0 */
    TCCR1A = _BV(WGM11);                          /* mode 14: fast PWM, TOP = ICR1 */
    TCCR1B = _BV(WGM13) | _BV(WGM12) | _BV(CS11); /* prescaler 8: 2 MHz */
#if defined(TCCR2B)
    TCCR2A = 0;
    TCCR2B = _BV(CS21); /* 2 MHz, normal mode */
    GTCCR = 0;          /* ... and released together: TCNT1 and TCNT2 count from 0 in step */
#endif
    TIMSK1 |= _BV(TOIE1);
}

/* The clock at `wraps` (within 256 of `now_wraps`) and `ticks`, from a snapshot of the
 * interrupt's counts (`base` = the low word of clock_base when clock_wraps was `now_wraps`): the
 * arithmetic runs with interrupts on, so the trigger's compare interrupt (trigger.c) is never
 * held off by it */
static uint32_t clock_from(uint32_t base, uint32_t now_wraps, uint32_t wraps, uint16_t ticks) {
    return base + (uint32_t)((int32_t)(wraps - now_wraps) * (int32_t)CLOCK_PERIOD_US) + (ticks >> 1);
}

uint32_t clock_at(uint32_t wraps, uint16_t ticks) {
    uint32_t base, now_wraps;
    ATOMIC_BLOCK(ATOMIC_RESTORESTATE) {
        base = clock_base.w.lo;
        now_wraps = clock_wraps;
    }
    return clock_from(base, now_wraps, wraps, ticks);
}

uint32_t clock_wraps_at(uint16_t ticks) {
    uint32_t w = clock_wraps;
    if ((TIFR1 & _BV(TOV1)) && ticks < TIMER_TOP / 2) w++; /* wrapped, interrupt not yet run */
    return w;
}

/* 1 when Timer1 wrapped at `t` and its interrupt has not run yet (interrupts off) */
static uint8_t wrap_pending(uint16_t t) { return (TIFR1 & _BV(TOV1)) && t < TIMER_TOP / 2; }

uint32_t clock_now_from_isr(void) {
    uint16_t t = TCNT1;
    uint32_t base = clock_base.w.lo;
    if (wrap_pending(t)) base += CLOCK_PERIOD_US;
    return base + (t >> 1);
}

uint32_t clock_ticks_from_isr(void) {
    uint16_t t = TCNT1;
    uint32_t base = clock_base.w.lo;
    if (wrap_pending(t)) base += CLOCK_PERIOD_US;
    return (base << 1) + t; /* (a wrap: 20000 µs, 40000 ticks) */
}

uint8_t clock_wait_prepare(uint32_t at_us, clock_wait_t *w) {
    uint32_t wraps;
    uint16_t t;
    ATOMIC_BLOCK(ATOMIC_RESTORESTATE) {
        t = TCNT1;
        wraps = clock_wraps_at(t);
    }
    int32_t d = (int32_t)(at_us - clock_at(wraps, t));
    if (d <= 0 || d >= (int32_t)CLOCK_PERIOD_US) return 0;
    w->from = t;
    w->ticks = (uint16_t)((uint16_t)d * 2 - (t & 1));
    return 1;
}

uint32_t clock_now(void) {
    uint32_t now;
    ATOMIC_BLOCK(ATOMIC_RESTORESTATE) { now = clock_now_from_isr(); }
    return now;
}

uint64_t board_clock(void) {
    /* interrupts off for the snapshot only (a few dozen cycles), the sums after */
    uint64_t base;
    uint16_t t;
    uint8_t wrapped;
    ATOMIC_BLOCK(ATOMIC_RESTORESTATE) {
        base = clock_base.us;
        t = TCNT1;
        wrapped = wrap_pending(t);
    }
    if (wrapped) base += CLOCK_PERIOD_US;
    return base + (t >> 1);
}

uint64_t clock_widen(uint32_t us) {
    uint64_t now = board_clock();
    return now + (int64_t)(int32_t)(us - (uint32_t)now);
}

/* ---- UART ---------------------------------------------------------------------------------- */
#if defined(UDR0)
#define UDR UDR0
#define UCSRA UCSR0A
#define UCSRB UCSR0B
#define UCSRC UCSR0C
#define UBRR UBRR0
#define U2X_ U2X0
#define RXEN RXEN0
#define TXEN TXEN0
#define RXCIE RXCIE0
#define UDRIE UDRIE0
#define UCSZ0 UCSZ00
#define UCSZ1 UCSZ01
#define RX_VECT USART_RX_vect
#define UDRE_VECT USART_UDRE_vect
#if defined(USART0_RX_vect)
#undef RX_VECT
#undef UDRE_VECT
#define RX_VECT USART0_RX_vect
#define UDRE_VECT USART0_UDRE_vect
#endif
#else /* ATmega32U4: the hardware UART is USART1 (its USB CDC is not used here) */
#define UDR UDR1
#define UCSRA UCSR1A
#define UCSRB UCSR1B
#define UCSRC UCSR1C
#define UBRR UBRR1
#define U2X_ U2X1
#define RXEN RXEN1
#define TXEN TXEN1
#define RXCIE RXCIE1
#define UDRIE UDRIE1
#define UCSZ0 UCSZ10
#define UCSZ1 UCSZ11
#define RX_VECT USART1_RX_vect
#define UDRE_VECT USART1_UDRE_vect
#endif

#define RX_SIZE 32  /* power of two */
#define TX_SIZE 256 /* power of two, <= 256 (8-bit indices) */

static volatile uint8_t rx_buf[RX_SIZE];
static volatile uint8_t rx_wraps[RX_SIZE]; /* low byte of the wrap count: 5 s of range */
static volatile uint16_t rx_ticks[RX_SIZE];
static volatile uint8_t rx_head, rx_tail;
static volatile uint16_t rx_dropped;
static volatile uint8_t tx_buf[TX_SIZE];
static volatile uint8_t tx_head, tx_tail, tx_count;

ISR(RX_VECT) {
    uint8_t b = UDR;
    uint8_t next = (rx_head + 1) & (RX_SIZE - 1);
    if (next == rx_tail) {
        rx_dropped++;
        return;
    }
    uint32_t w = clock_wraps;
    uint16_t t = TCNT1;
    if ((TIFR1 & _BV(TOV1)) && t < TIMER_TOP / 2) w++;
    rx_buf[rx_head] = b;
    rx_wraps[rx_head] = (uint8_t)w;
    rx_ticks[rx_head] = t;
    rx_head = next;
}

ISR(UDRE_VECT) {
    if (tx_count == 0) {
        UCSRB &= (uint8_t)~_BV(UDRIE);
        return;
    }
    UDR = tx_buf[tx_tail];
    tx_tail++; /* wraps at 256 */
    tx_count--;
}

void link_init(uint32_t baud) {
    UCSRA = _BV(U2X_);
    UBRR = (uint16_t)((F_CPU / 8 + baud / 2) / baud - 1);
    UCSRC = _BV(UCSZ1) | _BV(UCSZ0); /* 8N1 */
    UCSRB = _BV(RXEN) | _BV(TXEN) | _BV(RXCIE);
}

uint8_t link_read(uint8_t *b, uint32_t *rx_us) {
    uint8_t ok = 0, w8 = 0;
    uint16_t t = 0;
    uint32_t now_wraps = 0, base = 0;
    ATOMIC_BLOCK(ATOMIC_RESTORESTATE) { /* the byte and the counts; the sums after */
        if (rx_tail != rx_head) {
            *b = rx_buf[rx_tail];
            w8 = rx_wraps[rx_tail];
            t = rx_ticks[rx_tail];
            base = clock_base.w.lo;
            now_wraps = clock_wraps;
            rx_tail = (rx_tail + 1) & (RX_SIZE - 1);
            ok = 1;
        }
    }
    if (ok) {
        uint32_t w = (now_wraps & ~0xFFUL) | w8;
        if (w > now_wraps + 1) w -= 256; /* the byte came before the last 256-wrap */
        *rx_us = clock_from(base, now_wraps, w, t);
    }
    return ok;
}

void link_write(uint8_t b) {
    while (tx_count == TX_SIZE - 1) { /* full: wait for the interrupt to drain it */
    }
    ATOMIC_BLOCK(ATOMIC_RESTORESTATE) {
        tx_buf[tx_head] = b;
        tx_head++;
        tx_count++;
        UCSRB |= _BV(UDRIE);
    }
}

uint16_t link_tx_free(void) { return (uint16_t)(TX_SIZE - 1 - tx_count); }

uint16_t link_rx_dropped(void) { return rx_dropped; }
