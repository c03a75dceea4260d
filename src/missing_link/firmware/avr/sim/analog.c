/* Voltages on the ADC inputs (analog.h). */
#include "analog.h"

#include <math.h>
#include <stdio.h>

#include "avr_adc.h"

/* ---- Sharp: the datasheet curve (cm, V), linear between points (not the firmware's table) ---- */
static const double sharp_curve[][2] = {
    {0, 0.0},    {5, 1.6},     {10, 2.35},  {15, 2.75},  {20, 2.5},   {30, 2.0},
    {40, 1.55},  {50, 1.25},   {60, 1.05},  {70, 0.9},   {80, 0.8},   {90, 0.72},
    {100, 0.65}, {120, 0.55},  {150, 0.41}, {200, 0.35}, {300, 0.3},
};
static int sharp_mm = 800, sharp_channel = -1;

static void ain(int channel, uint32_t mv) {
    avr_raise_irq(avr_io_getirq(avr, AVR_IOCTL_ADC_GETIRQ, ADC_IRQ_ADC0 + channel), mv);
}

static void sharp_update(void) {
    double cm = sharp_mm / 10.0, v = 0.3;
    size_t n = sizeof sharp_curve / sizeof sharp_curve[0];
    for (size_t i = 1; i < n; i++) {
        if (cm <= sharp_curve[i][0]) {
            double c0 = sharp_curve[i - 1][0], v0 = sharp_curve[i - 1][1];
            v = v0 + (sharp_curve[i][1] - v0) * (cm - c0) / (sharp_curve[i][0] - c0);
            break;
        }
    }
    ain(sharp_channel, (uint32_t)lround(v * 1000));
}

int ain_add(int channel, uint32_t mv) {
    if (channel < 0 || channel > 15) return 0;
    ain(channel, mv);
    return 1;
}

void sharp_add(int channel) {
    sharp_channel = channel;
    sharp_update();
}

int analog_command(const char *cmd) {
    int v, mv;
    if (sscanf(cmd, "sharp %d", &v) == 1 && sharp_channel >= 0) {
        sharp_mm = v;
        sharp_update();
        printf("ok\n");
    } else if (sscanf(cmd, "ain %d %d", &v, &mv) == 2 && v >= 0 && v <= 15) {
        ain(v, (uint32_t)mv);
        printf("ok\n");
    } else {
        return 0;
    }
    return 1;
}
