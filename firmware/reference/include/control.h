/* control.h: the control logic (Hall capture, calibration, prediction, commutation, speed loop,
   faults). It never sees the hil_sil_* interface: board_sil.c calls these from the interrupts and
   the logic drives the hardware through board.h. */
#ifndef CONTROL_H
#define CONTROL_H

#include <stdint.h>

void ctl_power_on(uint8_t levels);
void ctl_hall_isr(uint32_t count, uint8_t pin, uint8_t levels, const int16_t adc[3]);
void ctl_control_isr(uint32_t count, const int16_t adc[3]);
void ctl_compare_isr(uint32_t count);

/* configuration changes (object dictionary) */
void ctl_restart_logic(void);           /* strategy write, applied table: restart with nvm */
void ctl_set_speed(float rpm);          /* the PI's set point and feed-forward, no restart */

/* read-backs */
float ctl_speed_rpm(void);              /* the controller's speed estimate; 0 when it has none */
void ctl_filter_diag(float q[3], float r[2]);
uint32_t ctl_guard_trips(void);
void ctl_filter_counters(uint32_t c[4]); /* gated, covariance repairs, divergence fades, band */
double ctl_last_prediction_s(void);     /* seconds on the timer's time base; 0 before any */

#endif /* CONTROL_H */
