/* platform.h on a PC: one thread, so the servo lock only checks that it is used as the
 * contract says. */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "native.h"
#include "platform.h"

static void contract_broken(const char *what) {
    fprintf(stderr, "platform contract broken: %s\n", what);
    abort();
}

/* --- the servo lock ---------------------------------------------------------------------- */

static bool lock_held;

void platform_servo_lock(void) {
    if (lock_held) {
        contract_broken("the servo lock taken while held");
    }
    lock_held = true;
}

void platform_servo_unlock(void) {
    if (!lock_held) {
        contract_broken("the servo lock released while not held");
    }
    lock_held = false;
}

/* --- output ------------------------------------------------------------------------------ */

void platform_write(const char *bytes, size_t length) {
    if (lock_held) {
        contract_broken("output written with the servo lock held");
    }
    native_output(bytes, length);
}

static uint32_t period_us;

void platform_servo_period_changed(uint32_t tick_us) {
    period_us = tick_us;
}

uint32_t native_servo_period_us(void) {
    return period_us;
}

/* --- the motion queue: a ring ------------------------------------------------------------ */

static int32_t queue[MOTION_QUEUE_CAPACITY];
static uint32_t queue_head;
static uint32_t queue_count;

bool mq_try_add(int32_t value) {
    if (queue_count == MOTION_QUEUE_CAPACITY) {
        return false;
    }
    queue[(queue_head + queue_count) % MOTION_QUEUE_CAPACITY] = value;
    queue_count++;
    return true;
}

bool mq_try_remove(int32_t *value) {
    if (queue_count == 0) {
        return false;
    }
    *value = queue[queue_head];
    queue_head = (queue_head + 1) % MOTION_QUEUE_CAPACITY;
    queue_count--;
    return true;
}

uint32_t mq_level(void) {
    return queue_count;
}

void mq_clear(void) {
    if (!lock_held) {
        contract_broken("the motion queue cleared without the servo lock");
    }
    queue_head = 0;
    queue_count = 0;
}

void mq_truncate(uint32_t count) {
    if (!lock_held) {
        contract_broken("the motion queue truncated without the servo lock");
    }
    if (count < queue_count) {
        queue_count = count;
    }
}

int32_t mq_peek(uint32_t index) {
    return index < queue_count ? queue[(queue_head + index) % MOTION_QUEUE_CAPACITY] : 0;
}

/* --- flash ------------------------------------------------------------------------------- */

static uint8_t flash[PLATFORM_FLASH_SECTORS][PLATFORM_FLASH_SECTOR_BYTES];
static int64_t fail_after = -1; /* bytes the next operation does before it fails; -1: none */
static uint32_t erases;
static uint32_t programs;

void native_flash_blank(void) {
    memset(flash, 0xff, sizeof flash);
    fail_after = -1;
    erases = 0;
    programs = 0;
}

bool native_flash_load(const char *path) {
    native_flash_blank();
    FILE *file = fopen(path, "rb");
    if (file == NULL) {
        return true;
    }
    size_t read = fread(flash, 1, sizeof flash, file);
    bool whole = read == sizeof flash && fgetc(file) == EOF;
    fclose(file);
    return whole;
}

bool native_flash_save(const char *path) {
    FILE *file = fopen(path, "wb");
    if (file == NULL) {
        return false;
    }
    bool written = fwrite(flash, 1, sizeof flash, file) == sizeof flash;
    return fclose(file) == 0 && written;
}

void native_flash_fail_next(uint32_t bytes) {
    fail_after = bytes;
}

uint32_t native_flash_erases(void) {
    return erases;
}

uint32_t native_flash_programs(void) {
    return programs;
}

/* How many of `length` bytes the operation does, and whether it then fails. */
static size_t allowed(size_t length, bool *fails) {
    *fails = fail_after >= 0;
    if (!*fails) {
        return length;
    }
    size_t done = (size_t)fail_after < length ? (size_t)fail_after : length;
    fail_after = -1;
    return done;
}

const uint8_t *platform_flash_sector(unsigned sector) {
    if (sector >= PLATFORM_FLASH_SECTORS) {
        contract_broken("a flash sector beyond the last");
    }
    return flash[sector];
}

bool platform_flash_erase(unsigned sector) {
    if (sector >= PLATFORM_FLASH_SECTORS) {
        contract_broken("a flash sector beyond the last");
    }
    if (lock_held) {
        contract_broken("flash erased with the servo lock held");
    }
    bool fails;
    size_t done = allowed(PLATFORM_FLASH_SECTOR_BYTES, &fails);
    memset(flash[sector], 0xff, done);
    erases++;
    return !fails;
}

bool platform_flash_program(unsigned sector, uint32_t offset, const uint8_t *page) {
    if (sector >= PLATFORM_FLASH_SECTORS || offset % PLATFORM_FLASH_PAGE_BYTES != 0 ||
        offset >= PLATFORM_FLASH_SECTOR_BYTES) {
        contract_broken("a flash page outside the sectors");
    }
    if (lock_held) {
        contract_broken("flash programmed with the servo lock held");
    }
    bool fails;
    size_t done = allowed(PLATFORM_FLASH_PAGE_BYTES, &fails);
    for (size_t i = 0; i < done; i++) {
        flash[sector][offset + i] &= page[i]; /* programming only clears bits */
    }
    programs++;
    return !fails;
}

/* The motor on the pins: the native build has none, so it reads a bare board (the counter
 * stands still, both switches open) and drives nothing. */
void platform_motor_pins_start(void) {}

void platform_motor_pins_encoder(int32_t kind) {
    (void)kind;
}

void platform_motor_pins_sample(motor_pins_sample_t *sample) {
    *sample = (motor_pins_sample_t){0};
}

void platform_motor_pins_drive(int32_t level, bool enable) {
    (void)level;
    (void)enable;
}

int32_t platform_motor_pins_full(void) {
    return 6250;
}

/* The outputs: the native build has no pins for them; core1's state holds their values. */
void platform_outputs_start(void) {}

void platform_outputs_form(const int16_t values[PLATFORM_OUTPUT_COUNT], output_pins_t *pins) {
    (void)values;
    *pins = (output_pins_t){{0, 0}};
}

void platform_outputs_write(const output_pins_t *pins) {
    (void)pins;
}

/* The step/direction outputs: the native build has no pins for them; the portable code's
 * simulated stepper counts the steps. */
void platform_steps_start(void) {}

void platform_steps_timing(uint32_t pulse_cycles, uint32_t setup_cycles, uint32_t tick_cycles) {
    (void)pulse_cycles;
    (void)setup_cycles;
    (void)tick_cycles;
}

void platform_steps_issue(int32_t steps, bool enable) {
    (void)steps;
    (void)enable;
}
