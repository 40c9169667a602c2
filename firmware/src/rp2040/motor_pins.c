/* The motor on the pins: quadrature decoding in a PIO state machine, PWM to a two-input
 * H-bridge, two debounced limit switches whose edges latch the counter at once, the probe
 * input read on each servo tick, and the enable output (pins.h has the pin map).
 *
 * Quadrature decoding runs quadrature.pio (assembled by the SDK's pioasm at build time):
 * 4x counting, the count pushed to the RX FIFO after every pass, the pins sampled at
 * least every 12 system clock cycles. The program sits at address 0. With an absolute
 * encoder (call 49 kind 1) the same state machine runs pwm_angle.pio instead (the two do not
 * fit pio0's 32 instructions together): the high time and the period of each frame of the
 * encoder's PWM on channel A, in system clock cycles; the portable code makes them an angle
 * (absenc.c). */
#include <stdbool.h>
#include <stdint.h>

#include "hardware/gpio.h"
#include "hardware/irq.h"
#include "hardware/pio.h"
#include "hardware/pwm.h"
#include "hardware/sync.h"
#include "hardware/timer.h"
#include "pico/platform.h"

#include "pins.h"
#include "pwm_angle.pio.h"
#include "quadrature.pio.h"
#include "platform.h"
#include "rp2040_platform.h"

/* A contact's debounced state: an edge is taken at once, then the contact is ignored for
 * USBMOTION_SWITCH_DEBOUNCE_US. */
typedef struct {
    bool closed;
    bool settling;         /* edge_us is less than the debounce time ago */
    uint32_t edge_us;
} debounced_t;

/* One limit switch: its debounced state, written by the GPIO interrupt and by the tick's
 * sample (both on core1, the sample with interrupts off). */
typedef struct {
    uint32_t pin;
    debounced_t contact;
    uint32_t edges;
    int32_t edge_count;
} limit_switch_t;

static limit_switch_t switches[2] = {{.pin = PIN_SWITCH_LOWER}, {.pin = PIN_SWITCH_UPPER}};

/* The probe: read by the tick's sample only (core1 latches its edge on that tick, with the
 * tick's count, as the simulated probe's). */
static debounced_t probe;
static uint32_t pwm_slice;
static int32_t pwm_full;   /* the compare level of a whole period high: TOP + 1 */
static bool started;

/* The encoder input: 0 quadrature, 1 the PWM angle reader. The reader's frames: a high part
 * waiting for the low part after it, and the newest whole frame. core1 (the tick's sample,
 * interrupts off) and core0 (platform_motor_pins_encoder, the servo lock held) only. */
static int32_t encoder_kind;
static bool pwm_pending;
static uint32_t pwm_pending_high;
static uint32_t pwm_frames;
static uint32_t pwm_high;
static uint32_t pwm_period;

/* The counter now: the FIFO's stale values dropped, then the next pass's push (at most 12
 * PIO cycles away). Interrupts off (the caller's). */
static int32_t __not_in_flash_func(read_count)(void) {
    PIO pio = QUADRATURE_PIO;
    for (unsigned i = 0; i < 5u && !pio_sm_is_rx_fifo_empty(pio, QUADRATURE_SM); i++) {
        (void)pio->rxf[QUADRATURE_SM];
    }
    while (pio_sm_is_rx_fifo_empty(pio, QUADRATURE_SM)) {
    }
    return (int32_t)pio->rxf[QUADRATURE_SM];
}

/* A contact reads `closed` at `now_us`: true when that is an edge, false when it is no
 * change or the contact is still settling from its last edge. */
static bool __not_in_flash_func(contact_reads)(debounced_t *contact, bool closed,
                                               uint32_t now_us) {
    if (contact->settling && now_us - contact->edge_us >= USBMOTION_SWITCH_DEBOUNCE_US) {
        contact->settling = false;
    }
    if (closed == contact->closed || contact->settling) {
        return false;
    }
    contact->closed = closed;
    contact->edge_us = now_us;
    contact->settling = true;
    return true;
}

/* A switch reads `closed` at `now_us`: an edge latches the counter now. */
static void __not_in_flash_func(switch_reads)(limit_switch_t *sw, bool closed, uint32_t now_us) {
    if (contact_reads(&sw->contact, closed, now_us)) {
        sw->edges += 1u;
        /* an absolute encoder's angle comes once a frame: its edges take the tick's count */
        sw->edge_count = encoder_kind == 0 ? read_count() : 0;
    }
}

/* The PWM reader's words since the last sample: a high part (bit 31 set, ~n_high), then the
 * low part after it (n_low) completes a frame (pwm_angle.pio has the cycles). Interrupts off
 * (the caller's). */
static void __not_in_flash_func(take_frames)(void) {
    PIO pio = QUADRATURE_PIO;
    while (!pio_sm_is_rx_fifo_empty(pio, QUADRATURE_SM)) {
        uint32_t word = pio->rxf[QUADRATURE_SM];
        if (word & 0x80000000u) {
            pwm_pending_high = ~word;
            pwm_pending = true;
        } else if (pwm_pending) {
            pwm_pending = false;
            pwm_high = 2u * pwm_pending_high + 3u;
            pwm_period = pwm_high + 2u * word + 4u;
            pwm_frames += 1u;
        }
    }
}

/* The encoder input's program at address 0 of pio0 and its state machine started. */
static void start_encoder_input(int32_t kind) {
    PIO pio = QUADRATURE_PIO;
    pio_sm_set_enabled(pio, QUADRATURE_SM, false);
    pio_clear_instruction_memory(pio);
    pio_sm_config config;
    uint32_t start;
    if (kind == 0) {
        pio_add_program_at_offset(pio, &quadrature_program, 0);
        config = quadrature_program_get_default_config(0);
        sm_config_set_in_shift(&config, false, false, 32);   /* left, no autopush */
        sm_config_set_out_shift(&config, true, false, 32);   /* right: out takes the low bits */
        start = quadrature_offset_start;
    } else {
        pio_add_program_at_offset(pio, &pwm_angle_program, 0);
        config = pwm_angle_program_get_default_config(0);
        sm_config_set_jmp_pin(&config, PIN_ENCODER_A);
        sm_config_set_fifo_join(&config, PIO_FIFO_JOIN_RX);   /* 8 words: 4 frames */
        start = pwm_angle_offset_start;
    }
    sm_config_set_in_pins(&config, PIN_ENCODER_A);
    sm_config_set_clkdiv_int_frac(&config, 1, 0);
    pio_sm_set_consecutive_pindirs(pio, QUADRATURE_SM, PIN_ENCODER_A, 2, false);
    pio_sm_init(pio, QUADRATURE_SM, start, &config);
    encoder_kind = kind;
    pwm_pending = false;
    pwm_frames = 0;
    pwm_high = 0;
    pwm_period = 0;
    pio_sm_set_enabled(pio, QUADRATURE_SM, true);
}

void platform_motor_pins_encoder(int32_t kind) {
    if (!started) {
        return;
    }
    uint32_t saved = save_and_disable_interrupts();   /* the switches' latch reads the input */
    start_encoder_input(kind);
    restore_interrupts(saved);
}

static void __not_in_flash_func(switch_irq)(void) {
    uint32_t now_us = timer_hw->timerawl;
    for (unsigned i = 0; i < 2u; i++) {
        limit_switch_t *sw = &switches[i];
        uint32_t events = gpio_get_irq_event_mask(sw->pin);
        if (events != 0u) {
            gpio_acknowledge_irq(sw->pin, events);
            switch_reads(sw, !gpio_get(sw->pin), now_us);
        }
    }
}

void platform_motor_pins_start(void) {
    for (uint32_t pin = PIN_ENCODER_A; pin <= PIN_ENCODER_B; pin++) {
        gpio_init(pin);
        gpio_set_dir(pin, GPIO_IN);
        gpio_pull_up(pin);
    }
    start_encoder_input(0);

    gpio_set_function(PIN_BRIDGE_IN1, GPIO_FUNC_PWM);
    gpio_set_function(PIN_BRIDGE_IN2, GPIO_FUNC_PWM);
    pwm_slice = pwm_gpio_to_slice_num(PIN_BRIDGE_IN1);
    pwm_full = (int32_t)(SYS_CLK_HZ / USBMOTION_PWM_HZ);
    pwm_config pwm = pwm_get_default_config();
    pwm_config_set_clkdiv_int(&pwm, 1);
    pwm_config_set_wrap(&pwm, (uint16_t)(pwm_full - 1));
    pwm_init(pwm_slice, &pwm, false);
    pwm_set_both_levels(pwm_slice, (uint16_t)pwm_full, (uint16_t)pwm_full);   /* 0 V: brake */
    pwm_set_enabled(pwm_slice, true);

    gpio_init(PIN_ENABLE);
    gpio_put(PIN_ENABLE, false);
    gpio_set_dir(PIN_ENABLE, GPIO_OUT);

    for (unsigned i = 0; i < 2u; i++) {
        limit_switch_t *sw = &switches[i];
        gpio_init(sw->pin);
        gpio_set_dir(sw->pin, GPIO_IN);
        gpio_pull_up(sw->pin);
    }
    gpio_init(PIN_PROBE);
    gpio_set_dir(PIN_PROBE, GPIO_IN);
    gpio_pull_up(PIN_PROBE);
    busy_wait_at_least_cycles(SYS_CLK_HZ / 100000u);   /* 10 us: the pull-ups charge the lines */
    for (unsigned i = 0; i < 2u; i++) {
        switches[i].contact.closed = !gpio_get(switches[i].pin);
    }
    probe.closed = !gpio_get(PIN_PROBE);
    started = true;
}

void motor_pins_core1_init(void) {
    if (!started) {
        return;
    }
    irq_set_exclusive_handler(IO_IRQ_BANK0, switch_irq);
    for (unsigned i = 0; i < 2u; i++) {
        gpio_set_irq_enabled(switches[i].pin, GPIO_IRQ_EDGE_FALL | GPIO_IRQ_EDGE_RISE, true);
    }
    /* above the servo alarm: an edge latches the counter even during a tick */
    irq_set_priority(IO_IRQ_BANK0, PICO_HIGHEST_IRQ_PRIORITY);
    irq_set_enabled(IO_IRQ_BANK0, true);
}

void __not_in_flash_func(platform_motor_pins_sample)(motor_pins_sample_t *sample) {
    uint32_t saved = save_and_disable_interrupts();
    if (encoder_kind == 0) {
        sample->count = read_count();
    } else {
        take_frames();
        sample->count = 0;
    }
    sample->pwm_frames = pwm_frames;
    sample->pwm_high = pwm_high;
    sample->pwm_period = pwm_period;
    uint32_t now_us = timer_hw->timerawl;
    int32_t closed = 0;
    for (unsigned i = 0; i < 2u; i++) {
        limit_switch_t *sw = &switches[i];
        switch_reads(sw, !gpio_get(sw->pin), now_us);   /* the end of a debounce wait */
        closed |= sw->contact.closed ? (int32_t)(1u << i) : 0;
        sample->edges[i] = sw->edges;
        sample->edge_count[i] = sw->edge_count;
    }
    sample->switches = closed;
    (void)contact_reads(&probe, !gpio_get(PIN_PROBE), now_us);
    sample->probe = probe.closed ? 1 : 0;
    restore_interrupts(saved);
}

void __not_in_flash_func(platform_motor_pins_drive)(int32_t level, bool enable) {
    /* slow decay (drive / brake): one input stays high, the other is low for |level| of
     * the period, so the motor sees the supply or a short, |level| / full of the time */
    uint32_t magnitude = level < 0 ? 0u - (uint32_t)level : (uint32_t)level;
    if (magnitude > (uint32_t)pwm_full) {
        magnitude = (uint32_t)pwm_full;
    }
    uint16_t high = (uint16_t)pwm_full;
    uint16_t pulsed = (uint16_t)((uint32_t)pwm_full - magnitude);
    if (level >= 0) {
        pwm_set_both_levels(pwm_slice, high, pulsed);
    } else {
        pwm_set_both_levels(pwm_slice, pulsed, high);
    }
    gpio_put(PIN_ENABLE, enable);
}

int32_t platform_motor_pins_full(void) {
    return (int32_t)(SYS_CLK_HZ / USBMOTION_PWM_HZ);
}
