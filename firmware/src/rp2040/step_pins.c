/* The step/direction outputs of call 44's drives 1 and 2 (platform.h): a placeholder that
 * drives no pin yet. The PIO step generator replaces it: STEP pulses of pulse_cycles high and
 * at least as long low, spread evenly over the tick after setup_cycles from a change of DIR,
 * and the driver's enable, in periods of the 125 MHz step clock. */
#include <stdbool.h>
#include <stdint.h>

#include "pico.h"

#include "platform.h"

void platform_steps_start(void) {}

void platform_steps_timing(uint32_t pulse_cycles, uint32_t setup_cycles, uint32_t tick_cycles) {
    (void)pulse_cycles;
    (void)setup_cycles;
    (void)tick_cycles;
}

void __not_in_flash_func(platform_steps_issue)(int32_t steps, bool enable) {
    (void)steps;
    (void)enable;
}
