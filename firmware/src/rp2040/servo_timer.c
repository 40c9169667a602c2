/* core1: the servo tick from a hardware alarm, and the servo lock.
 *
 * The alarm is armed on absolute target times (target += period), so the ticks do not drift
 * with the interrupt latency. A tick whose target has already passed runs at once: ticks are
 * caught up, never skipped. */
#include <stdbool.h>
#include <stdint.h>

#include "hardware/irq.h"
#include "hardware/sync.h"
#include "hardware/timer.h"
#include "pico/flash.h"
#include "pico/multicore.h"
#include "pico/platform.h"

#include "device.h"
#include "platform.h"
#include "rp2040_platform.h"

/* Alarm 3 is the SDK's default alarm pool (core0, sleep and timeouts); the servo takes 0. */
#define SERVO_ALARM_NUM 0u
#define SERVO_ALARM_BIT (1u << SERVO_ALARM_NUM)
#define SERVO_ALARM_IRQ (TIMER_IRQ_0 + SERVO_ALARM_NUM)

/* core1 to core0 through the FIFO: ticking, and a lockout victim for flash writes */
#define SERVO_CORE1_READY 0x5E4D0001u

volatile uint64_t usbmotion_ticks_done;

static spin_lock_t *servo_lock;
static uint32_t servo_lock_saved_irq[NUM_CORES];

/* The schedule, guarded by schedule_lock (core1's alarm interrupt and core0's period change). */
static spin_lock_t *schedule_lock;
static uint64_t scheduled_us; /* target time of the next tick */
static uint32_t period_us;
static bool in_tick;

void servo_lock_init(void) {
    servo_lock = spin_lock_init((uint)spin_lock_claim_unused(true));
    schedule_lock = spin_lock_init((uint)spin_lock_claim_unused(true));
}

void __not_in_flash_func(platform_servo_lock)(void) {
    uint32_t saved = spin_lock_blocking(servo_lock);
    servo_lock_saved_irq[get_core_num()] = saved;
}

void __not_in_flash_func(platform_servo_unlock)(void) {
    spin_unlock(servo_lock, servo_lock_saved_irq[get_core_num()]);
}

/* Arms the alarm for target_us (schedule_lock held). Returns false, with the alarm disarmed
 * and its flag cleared, when the target has already passed. */
static bool __not_in_flash_func(arm_alarm)(uint64_t target_us) {
    timer_hw->alarm[SERVO_ALARM_NUM] = (uint32_t)target_us;
    if ((int64_t)(target_us - time_us_64()) > 0) {
        return true;
    }
    timer_hw->armed = SERVO_ALARM_BIT;
    timer_hw->intr = SERVO_ALARM_BIT;
    return false;
}

static void __not_in_flash_func(servo_alarm_irq)(void) {
    step_pins_tick(); /* first thing: the step generator's tick clock restarts here */
    timer_hw->intr = SERVO_ALARM_BIT;
    hw_clear_bits(&timer_hw->intf, SERVO_ALARM_BIT);
    uint32_t saved = spin_lock_blocking(schedule_lock);
    in_tick = true;
    spin_unlock(schedule_lock, saved);
    bool armed;
    do {
        device_servo_tick();
        usbmotion_ticks_done = usbmotion_ticks_done + 1;
        __sev(); /* core0 prints what the tick recorded */
        saved = spin_lock_blocking(schedule_lock);
        scheduled_us += period_us;
        armed = arm_alarm(scheduled_us);
        in_tick = !armed;
        spin_unlock(schedule_lock, saved);
    } while (!armed);
}

void platform_servo_period_changed(uint32_t tick_us) {
    uint32_t saved = spin_lock_blocking(schedule_lock);
    if (!in_tick) {
        /* move the pending tick: one new period after the last tick's target */
        scheduled_us = scheduled_us - period_us + tick_us;
        if (!arm_alarm(scheduled_us)) {
            hw_set_bits(&timer_hw->intf, SERVO_ALARM_BIT); /* due already: run it now */
        }
    }
    /* during a tick, the interrupt schedules the next one with the new period */
    period_us = tick_us;
    spin_unlock(schedule_lock, saved);
}

void servo_start(void) {
    multicore_launch_core1(servo_core1_main);
    while (multicore_fifo_pop_blocking() != SERVO_CORE1_READY) {
    }
}

void servo_core1_main(void) {
    flash_safe_execute_core_init(); /* core0's flash writes lock this core out */
    motor_pins_core1_init();
    hardware_alarm_claim(SERVO_ALARM_NUM);
    irq_set_exclusive_handler(SERVO_ALARM_IRQ, servo_alarm_irq);
    hw_set_bits(&timer_hw->inte, SERVO_ALARM_BIT);
    irq_set_enabled(SERVO_ALARM_IRQ, true); /* in core1's NVIC: the tick runs on core1 */
    uint32_t saved = spin_lock_blocking(schedule_lock);
    period_us = device_tick_us();
    scheduled_us = time_us_64() + period_us;
    if (!arm_alarm(scheduled_us)) {
        hw_set_bits(&timer_hw->intf, SERVO_ALARM_BIT);
    }
    spin_unlock(schedule_lock, saved);
    multicore_fifo_push_blocking(SERVO_CORE1_READY);
    for (;;) {
        __wfe();
    }
}
