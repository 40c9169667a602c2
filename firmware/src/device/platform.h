/* What the portable device code needs from the platform it runs on (the RP2040, or the
 * native build the tests use). The portable code never touches hardware. */
#ifndef USBMOTION_PLATFORM_H
#define USBMOTION_PLATFORM_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

/* Output, core0 only: queue the bytes for USB (blocks while the host reads them). */
void platform_write(const char *bytes, size_t length);

/* The servo lock. core1 holds it for the whole of one servo tick; core0 holds it while it
 * reads or changes core1's state (the seed's "core1 stops its loop, copies, resumes").
 * Short critical sections only. */
void platform_servo_lock(void);
void platform_servo_unlock(void);

/* The servo period changed (call 5): the platform re-arms its periodic tick. */
void platform_servo_period_changed(uint32_t tick_us);

/* The motion queue: on the chip a queue_t of int32_t, capacity MOTION_QUEUE_CAPACITY. */
#define MOTION_QUEUE_CAPACITY 1000u
bool mq_try_add(int32_t value);      /* core0 */
bool mq_try_remove(int32_t *value);  /* core1 */
uint32_t mq_level(void);
void mq_clear(void);                 /* core0, with the servo lock held */
void mq_truncate(uint32_t count);    /* core0, with the servo lock held: keep the first count */
int32_t mq_peek(uint32_t index);     /* core0: the index-th value from the head */

/* Flash for the flash variables: PLATFORM_FLASH_SECTORS erase sectors at the end of the
 * flash, each PLATFORM_FLASH_SECTOR_BYTES, programmed a PLATFORM_FLASH_PAGE_BYTES page at a
 * time (erased bytes read 0xff). Two sectors, so a new record can be written while the old
 * one is still whole: a power cut leaves the old value or the new one. */
#define PLATFORM_FLASH_SECTORS 2u
#define PLATFORM_FLASH_SECTOR_BYTES 4096u
#define PLATFORM_FLASH_PAGE_BYTES 256u
const uint8_t *platform_flash_sector(unsigned sector);   /* memory-mapped, read-only */
bool platform_flash_erase(unsigned sector);              /* false: the erase failed */
bool platform_flash_program(unsigned sector, uint32_t offset, const uint8_t *page);
                                                         /* one page; false: it failed */

/* The motor on the pins (call 39): an H-bridge, a quadrature encoder, two limit switches and
 * a probe input.
 * Started once by core0 at power-up when the flash selects them (before core1 ticks); read
 * and driven by core1 on each tick. A platform without them (the native build) reads a
 * bare board: the counter stands still and both switches and the probe are open. */
typedef struct {
    int32_t count;            /* the quadrature counter (4 counts per encoder cycle, wraps) */
    int32_t switches;         /* debounced: bit 0 lower closed, bit 1 upper closed */
    uint32_t edges[2];        /* debounced edges of each switch since the start, mod 2^32 */
    int32_t edge_count[2];    /* the counter when each switch's last edge happened */
    int32_t probe;            /* the probe input as it reads now: 1 closed */
    /* The absolute encoder (platform_motor_pins_encoder(1)): its PWM, the newest whole frame;
     * count and edge_count are then 0 (the count is the portable code's, from the frames). */
    uint32_t pwm_frames;      /* whole frames measured since the reader started, mod 2^32 */
    uint32_t pwm_high;        /* the newest one's high time, system clock cycles */
    uint32_t pwm_period;      /* ... and its period, rising edge to rising edge */
} motor_pins_sample_t;
void platform_motor_pins_start(void);                          /* core0 */
/* core0, with the servo lock held: the encoder input, 0 the quadrature decoder on channels A
 * and B, 1 the PWM angle reader on channel A (frames counted from 0, none yet). */
void platform_motor_pins_encoder(int32_t kind);
void platform_motor_pins_sample(motor_pins_sample_t *sample);  /* core1 */
/* core1: the bridge's voltage as a signed level, -full..full (full: the whole supply; the
 * sign picks the input), and the enable output. */
void platform_motor_pins_drive(int32_t level, bool enable);
int32_t platform_motor_pins_full(void);

/* The outputs of call 42 (0 and 1 digital, 2 and 3 PWM), on either motor. Started once by
 * core0 at power-up, every output at 0. core0 puts the outputs' values (per mille of full
 * duty, a digital output on for 1000) in the form the platform writes them when it queues a
 * change (platform_outputs_form); core1 writes that form on the tick the change applies
 * (platform_outputs_write), every output at once, and the form of every output at 0 (all
 * zero words) on the tick a fault latches. A platform without them (the native build) keeps
 * nothing. */
#define PLATFORM_OUTPUT_COUNT 4u
typedef struct {
    uint32_t words[2];
} output_pins_t;
void platform_outputs_start(void);                                   /* core0 */
void platform_outputs_form(const int16_t values[PLATFORM_OUTPUT_COUNT],
                           output_pins_t *pins);                     /* core0 */
void platform_outputs_write(const output_pins_t *pins);              /* core1 */

/* Step/direction outputs (call 44's drives 1 and 2), on either motor: STEP, DIR and the driver's enable.
 * Timing in periods of the 125 MHz step clock (usbmotion.protocol.table.STEP_CLOCK_HZ). */
void platform_steps_start(void);                                     /* core0, power-up */
void platform_steps_timing(uint32_t pulse_cycles, uint32_t setup_cycles, uint32_t tick_cycles); /* core0, when calls 5/46 change it */
void platform_steps_issue(int32_t steps, bool enable);               /* core1, every tick of a step drive, with the tick's signed steps */

#endif
