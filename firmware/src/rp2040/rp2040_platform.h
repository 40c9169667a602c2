/* The RP2040 platform's own parts, shared between its files (not seen by the portable code). */
#ifndef USBMOTION_RP2040_PLATFORM_H
#define USBMOTION_RP2040_PLATFORM_H

#include <stdint.h>

/* Servo ticks completed since power-up, incremented as the last action of every tick (after
 * device_servo_tick returns). Read by address from the ELF by the emulator harness. */
extern volatile uint64_t usbmotion_ticks_done;

/* core0, before core1 starts */
void servo_lock_init(void);
void motion_queue_init(void);

/* core0: launches core1 and returns once it ticks and can be locked out for flash writes */
void servo_start(void);
/* core1's entry: flash lockout victim, the periodic servo alarm, then sleep between ticks */
void servo_core1_main(void);

/* core1, before its first tick: the switches' interrupt, when the motor is on the pins */
void motor_pins_core1_init(void);

/* core1, first thing in the servo alarm's interrupt (before its ticks): the step generator
 * takes a timing core0 changed, and restarts its tick clock at this instant when the period
 * did (step_pins.c; inline: one comparison when nothing is new) */
extern volatile uint32_t step_timing_staged;
extern uint32_t step_timing_taken;
void step_pins_take_timing(void);
static inline void step_pins_tick(void) {
    if (step_timing_staged != step_timing_taken) {
        step_pins_take_timing();
    }
}

/* core0: bring up USB and run the main loop; never returns */
void usb_cdc_run(void);

#endif
