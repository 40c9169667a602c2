/* The device as the platform sees it: what core0's main loop and core1's tick call. */
#ifndef USBMOTION_DEVICE_H
#define USBMOTION_DEVICE_H

#include <stddef.h>
#include <stdint.h>

/* core0 at boot, before core1 starts: RAM defaults, flash variables, servo state. */
void device_power_up(void);
/* core0: bytes from USB, split anywhere; each complete line is interpreted at once. */
void device_feed(const uint8_t *data, size_t length);
/* core0's main loop: print the diagnostics and alarm records core1 wrote, in order. */
void device_poll(void);
/* core1: one servo tick (takes the servo lock itself). */
void device_servo_tick(void);
/* The servo period now, microseconds. */
uint32_t device_tick_us(void);

#endif
