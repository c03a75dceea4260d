/* What the rig measures at the firmware's pins and registers (probes.h). */
#include "probes.h"

#include <stdio.h>
#include <string.h>

#include "avr_adc.h"
#include "avr_ioport.h"

/* ---- the board's clock ---------------------------------------------------------------------------
 * The firmware's clock is Timer1 at 2 MHz from the moment TCCR1B's clock bits are set: that
 * cycle (seen after the instruction that set them, at most 2 cycles late) is its zero, so an
 * event at the pins can be put in the board's µs to compare with the ticks it was asked for. */
static avr_cycle_count_t t1_start;

double board_us_at(avr_cycle_count_t c) {
    return c < t1_start ? -1.0 : (double)(c - t1_start) * 1e6 / avr->frequency;
}

/* ---- servo: OC1A ---------------------------------------------------------------------------------
 * The frame period is measured at the pin (rising edges).  The pulse width is read from the
 * timer's registers as the hardware would produce it (OCR1A ticks at the prescaled clock, output
 * enabled by COM1A1 and DDR): simavr 1.6 raises OC1A at each frame but drops it again within a
 * few cycles whatever OCR1A holds, so the pin's high time says nothing about the width. */
static uint8_t servo_pin = 1; /* PB1 (Uno D9); PB5 on the Mega and the Leonardo */
static avr_cycle_count_t servo_rise, servo_period;
static unsigned servo_frames;

static void servo_hook(struct avr_irq_t *irq, uint32_t value, void *param) {
    (void)irq;
    (void)param;
    if (value) {
        if (servo_rise) servo_period = avr->cycle - servo_rise;
        servo_rise = avr->cycle;
        servo_frames++;
    }
}

static double servo_pulse_us(void) {
    enum { TCCR1A = 0x80, TCCR1B = 0x81, OCR1AL = 0x88, DDRB = 0x24 };
    static const unsigned prescale[8] = {0, 1, 8, 64, 256, 1024, 0, 0};
    unsigned ps = prescale[avr->data[TCCR1B] & 7];
    if (!(avr->data[TCCR1A] & 0x80) || !(avr->data[DDRB] & (1u << servo_pin)) || !ps) return 0;
    unsigned ocr = avr->data[OCR1AL] | (avr->data[OCR1AL + 1] << 8);
    return (double)ocr * ps * 1e6 / avr->frequency;
}

/* ---- the trigger: OC2A ---------------------------------------------------------------------------
 * OC2A as the datasheet has it, from the registers: Timer2 counts from the cycle its clock was
 * started, one count per 8 cycles (prescaler 8, the only one the firmware uses); a compare match
 * (the count going from OCR2A to OCR2A + 1) applies COM2A to the pin: toggle, clear or set;
 * COM2A = 0 hands the pin back to PORTB.  A write of FOC2A (TCCR2B bit 7, a strobe that reads 0:
 * the rig clears it) forces that at once, without a flag, as the datasheet has it (simavr 1.6
 * ignores it).  The rig does not take the pin from simavr's timer: 1.6 also drives it at every
 * overflow in normal mode (its PWM modes' behaviour; fixed upstream since).  Checked after every
 * instruction with the registers as they were before it, so a match is placed on its exact
 * cycle. */
static uint8_t trig_pin = 3; /* OC2A: PB3 (Uno D11); PB4 on the Mega (D10) */
static avr_cycle_count_t trig_rise, trig_fall;
static unsigned trig_edges;
static avr_cycle_count_t t2_start, t2_seen;
static uint8_t oc2a, trig_level, ocr2a_was, com2a_was;

static void trig_edge(uint8_t level, avr_cycle_count_t at) {
    if (level == trig_level) return;
    trig_level = level;
    trig_edges++;
    if (level) trig_rise = at;
    else trig_fall = at;
}

/* a compare match (or one forced) with compare mode `com`: toggle, clear or set; 0: none */
static void oc2a_apply(uint8_t com, avr_cycle_count_t at) {
    if (!com) return;
    if (com == 1) oc2a ^= 1;
    else if (com == 2) oc2a = 0;
    else oc2a = 1;
    trig_edge(oc2a, at);
}

static void trig_watch(void) {
    enum { TCCR2A = 0xB0, TCCR2B = 0xB1, OCR2A = 0xB3, PORTB = 0x25 };
    if (!t2_start) {
        if ((avr->data[TCCR2B] & 7) != 2) return;
        t2_start = t2_seen = avr->cycle;
    }
    uint64_t n0 = (t2_seen - t2_start) / 8, n1 = (avr->cycle - t2_start) / 8; /* counts so far */
    if (com2a_was && n1 > n0) {
        uint64_t to = (uint64_t)((uint8_t)(ocr2a_was + 1) - (uint8_t)(n0 + 1)) & 0xFF; /* counts */
        if (to < n1 - n0) oc2a_apply(com2a_was, t2_start + (n0 + 1 + to) * 8); /* reached OCR2A + 1 */
    }
    t2_seen = avr->cycle;
    ocr2a_was = avr->data[OCR2A];
    com2a_was = avr->data[TCCR2A] >> 6;
    if (avr->data[TCCR2B] & 0x80) { /* FOC2A: a strobe (it reads 0), the compare mode applied now */
        avr->data[TCCR2B] &= 0x7F;
        oc2a_apply(com2a_was, avr->cycle);
    }
    if (!com2a_was) trig_edge((avr->data[PORTB] >> trig_pin) & 1, avr->cycle);
}

/* ---- ADC0's conversions, the stack ----------------------------------------------------------- */
#define ADC_LOG 64
static avr_cycle_count_t adc_starts[ADC_LOG];
static unsigned adc_n;
static uint16_t sp_min = 0xFFFF;
static uint32_t sp_min_pc; /* where it was reached */

static void adc_hook(struct avr_irq_t *irq, uint32_t value, void *param) {
    (void)irq;
    (void)param;
    /* an avr_adc_mux_t's bits (kind 0-2, gain, diff, src 19-31) in the low 32 */
    if ((value & 7) == ADC_MUX_SINGLE && (value >> 19) == 0) adc_starts[adc_n++ % ADC_LOG] = avr->cycle;
}

static void stack_watch(void) {
    uint16_t sp = (uint16_t)(avr->data[0x5D] | (avr->data[0x5E] << 8));
    /* SPH is written before SPL (with SREG restored between): no reading until SPL is too */
    int half = 0;
    for (int k = 0; k < 4; k += 2) {
        uint16_t op = (uint16_t)(avr->flash[avr->pc + k] | (avr->flash[avr->pc + k + 1] << 8));
        half |= (op & 0xFE0F) == 0xBE0D; /* out 0x3d (SPL), rN */
    }
    if (!half && sp < sp_min && sp > 0x100) {
        sp_min = sp;
        sp_min_pc = avr->pc;
    }
}

/* ---- interrupts off ---------------------------------------------------------------------------
 * The longest stretch with SREG's I bit clear since the firmware first set it, by where it
 * began: an interrupt routine (its vector: the routine runs with I clear) or the main loop (an
 * atomic block).  An edge's interrupt waits for the stretch in flight, then for any
 * higher-priority routine pending meanwhile.  Measured from the first instruction seen with I
 * clear (a routine: after its entry's 4 cycles) to the one that set it again, from the first
 * time it is asked on (a look after every instruction: the rig's runs that never ask skip it). */
#define PLACES 65 /* vectors 0-63; 64: the main loop */
static avr_cycle_count_t off_since, off_max[PLACES];
static int off_place, irq_seen, irq_asked;

static void irq_watch(void) {
    if (avr->sreg[S_I]) {
        irq_seen = 1;
        if (off_since && avr->cycle - off_since > off_max[off_place]) off_max[off_place] = avr->cycle - off_since;
        off_since = 0;
    } else if (irq_seen && !off_since) {
        unsigned size = avr->vector_size ? avr->vector_size : 4, v = avr->pc / size;
        off_since = avr->cycle;
        off_place = avr->pc % size == 0 && v < PLACES - 1 ? (int)v : PLACES - 1;
    }
}

static void irqoff_say(void) {
    irq_asked = 1;
    printf("irqoff");
    for (int k = 0; k < PLACES; k++) {
        if (!off_max[k]) continue;
        if (k == PLACES - 1) printf(" main:%llu", (unsigned long long)off_max[k]);
        else printf(" %d:%llu", k, (unsigned long long)off_max[k]);
        off_max[k] = 0;
    }
    printf("\n");
}

void probes_watch(void) {
    if (!t1_start && (avr->data[0x81] & 7)) t1_start = avr->cycle; /* TCCR1B */
    trig_watch();
    stack_watch();
    if (irq_asked) irq_watch();
}

void probes_init(const char *mcu) {
    if (strcmp(mcu, "atmega328p") != 0) { /* Mega/Leonardo: OC1A = PB5, OC2A = PB4 */
        servo_pin = 5;
        trig_pin = 4;
    }
    avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_IOPORT_GETIRQ('B'), servo_pin), servo_hook,
                            NULL);
    avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_ADC_GETIRQ, ADC_IRQ_OUT_TRIGGER), adc_hook,
                            NULL);
}

int probes_command(const char *cmd) {
    if (!strncmp(cmd, "pulse", 5)) {
        printf("pulse %.1f period %.1f frames %u\n", servo_pulse_us(),
               (double)servo_period * 1e6 / avr->frequency, servo_frames);
    } else if (!strncmp(cmd, "trig", 4)) {
        printf("trig %u %.3f %.3f\n", trig_edges, trig_rise ? board_us_at(trig_rise) : -1.0,
               trig_fall ? board_us_at(trig_fall) : -1.0);
    } else if (!strncmp(cmd, "adc", 3)) {
        unsigned n = adc_n < ADC_LOG ? adc_n : ADC_LOG;
        printf("adc %u", n);
        for (unsigned i = adc_n - n; i < adc_n; i++) printf(" %.3f", board_us_at(adc_starts[i % ADC_LOG]));
        printf("\n");
    } else if (!strncmp(cmd, "irqoff", 6)) {
        irqoff_say();
    } else if (!strncmp(cmd, "stack", 5)) {
        printf("stack 0x%04x 0x%x\n", sp_min, (unsigned)sp_min_pc);
    } else {
        return 0;
    }
    return 1;
}
