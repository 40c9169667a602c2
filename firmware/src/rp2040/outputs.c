/* The outputs of call 42 on their pins (pins.h): two digital outputs and two PWM outputs on
 * one PWM slice, set by core1 on the tick a change applies. */
#include <stdbool.h>
#include <stdint.h>

#include "hardware/gpio.h"
#include "hardware/pwm.h"
#include "hardware/structs/sio.h"
#include "pico/platform.h"

#include "pins.h"
#include "platform.h"

#define OUTPUT_PWM_FULL (SYS_CLK_HZ / USBMOTION_OUTPUT_PWM_HZ)   /* a whole period high */
#define OUTPUT_PWM_PER_MILLE (OUTPUT_PWM_FULL / 1000u)
_Static_assert(OUTPUT_PWM_FULL % 1000u == 0 && OUTPUT_PWM_FULL <= 65536u,
               "USBMOTION_OUTPUT_PWM_HZ must divide the system clock into a multiple of 1000"
               " steps, at most 65,536");
_Static_assert(PIN_OUTPUT_3 == PIN_OUTPUT_2 + 1u && PIN_OUTPUT_2 % 2u == 0,
               "the PWM outputs are one slice's A and B");

#define OUTPUT_PWM_SLICE ((PIN_OUTPUT_2 >> 1u) & 7u)   /* pwm_gpio_to_slice_num */

/* The PWM outputs' compare levels (A, B), written to the slice's CC register together. */
static uint32_t pwm_levels[2];

void platform_outputs_start(void) {
    static const uint32_t digital[2] = {PIN_OUTPUT_0, PIN_OUTPUT_1};
    for (unsigned i = 0; i < 2u; i++) {
        gpio_init(digital[i]);
        gpio_put(digital[i], false);
        gpio_set_dir(digital[i], GPIO_OUT);
    }
    pwm_config config = pwm_get_default_config();
    pwm_config_set_clkdiv_int(&config, 1);
    pwm_config_set_wrap(&config, (uint16_t)(OUTPUT_PWM_FULL - 1u));
    pwm_init(OUTPUT_PWM_SLICE, &config, false);
    pwm_levels[0] = pwm_levels[1] = 0;
    pwm_set_both_levels(OUTPUT_PWM_SLICE, 0, 0);
    gpio_set_function(PIN_OUTPUT_2, GPIO_FUNC_PWM);
    gpio_set_function(PIN_OUTPUT_3, GPIO_FUNC_PWM);
    pwm_set_enabled(OUTPUT_PWM_SLICE, true);
}

/* The digital outputs' pins as SIO masks. */
static const uint32_t digital_masks[2] = {1u << PIN_OUTPUT_0, 1u << PIN_OUTPUT_1};

void __not_in_flash_func(platform_output_set)(uint32_t output, int32_t value) {
    if (output >= 2u) {
        pwm_levels[output - 2u] = (uint32_t)value * OUTPUT_PWM_PER_MILLE;
        pwm_hw->slice[OUTPUT_PWM_SLICE].cc = pwm_levels[0] | pwm_levels[1] << PWM_CH0_CC_B_LSB;
    } else if (value != 0) {
        sio_hw->gpio_set = digital_masks[output];
    } else {
        sio_hw->gpio_clr = digital_masks[output];
    }
}
