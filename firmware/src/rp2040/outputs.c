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
    pwm_set_both_levels(OUTPUT_PWM_SLICE, 0, 0);
    gpio_set_function(PIN_OUTPUT_2, GPIO_FUNC_PWM);
    gpio_set_function(PIN_OUTPUT_3, GPIO_FUNC_PWM);
    pwm_set_enabled(OUTPUT_PWM_SLICE, true);
}

/* The digital outputs' pins as SIO masks. */
#define OUTPUT_0_MASK (1u << PIN_OUTPUT_0)
#define OUTPUT_1_MASK (1u << PIN_OUTPUT_1)

/* The form (platform.h): word 0 the digital outputs' pins that are high, an SIO mask; word 1
 * the PWM slice's compare register, output 2's level in its A half and output 3's in its B
 * half. Every output at 0 is both words 0. */
void platform_outputs_form(const int16_t values[PLATFORM_OUTPUT_COUNT], output_pins_t *pins) {
    pins->words[0] = (values[0] != 0 ? OUTPUT_0_MASK : 0u) | (values[1] != 0 ? OUTPUT_1_MASK : 0u);
    pins->words[1] = (uint32_t)values[2] * OUTPUT_PWM_PER_MILLE |
                     (uint32_t)values[3] * OUTPUT_PWM_PER_MILLE << PWM_CH0_CC_B_LSB;
}

void __not_in_flash_func(platform_outputs_write)(const output_pins_t *pins) {
    uint32_t high = pins->words[0];
    sio_hw->gpio_set = high;
    sio_hw->gpio_clr = high ^ (OUTPUT_0_MASK | OUTPUT_1_MASK);
    pwm_hw->slice[OUTPUT_PWM_SLICE].cc = pins->words[1];
}
