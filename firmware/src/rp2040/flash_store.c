/* The flash variables' sectors: the last PLATFORM_FLASH_SECTORS 4 KiB sectors of the flash,
 * read through XIP, erased and programmed inside flash_safe_execute while core1 is locked out.
 * The portable code decides what goes where (two sectors: a record is written whole before
 * the old one is erased). */
#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include "hardware/flash.h"
#include "hardware/sync.h"
#include "pico/flash.h"
#include "pico/multicore.h"

#include "platform.h"

_Static_assert(PLATFORM_FLASH_SECTOR_BYTES == FLASH_SECTOR_SIZE, "the RP2040's flash sector");
_Static_assert(PLATFORM_FLASH_PAGE_BYTES == FLASH_PAGE_SIZE, "the RP2040's flash page");

#define FLASH_STORE_OFFSET (PICO_FLASH_SIZE_BYTES - PLATFORM_FLASH_SECTORS * FLASH_SECTOR_SIZE)
/* Time core1 has to acknowledge the lockout (it does so between two servo ticks). */
#define FLASH_STORE_TIMEOUT_MS 100

struct flash_job {
    uint32_t offset; /* from the start of the flash */
    const uint8_t *page; /* NULL: erase the sector at offset */
};

/* RAM: flash_range_program reads its source while XIP is off */
static uint8_t page_buffer[FLASH_PAGE_SIZE];

static void __not_in_flash_func(flash_job_run)(void *param) {
    const struct flash_job *job = param;
    if (job->page == NULL) {
        flash_range_erase(job->offset, FLASH_SECTOR_SIZE);
    } else {
        flash_range_program(job->offset, page_buffer, FLASH_PAGE_SIZE);
    }
}

static bool flash_job_execute(struct flash_job *job) {
    if (multicore_lockout_victim_is_initialized(1)) {
        return flash_safe_execute(flash_job_run, job, FLASH_STORE_TIMEOUT_MS) == PICO_OK;
    }
    /* core1 still waits in the bootrom for its launch (device_power_up runs before it), where
     * flash_safe_execute refuses: with no other core to lock out, masking this core's
     * interrupts is enough. */
    uint32_t saved = save_and_disable_interrupts();
    flash_job_run(job);
    restore_interrupts(saved);
    return true;
}

const uint8_t *platform_flash_sector(unsigned sector) {
    if (sector >= PLATFORM_FLASH_SECTORS) {
        return NULL;
    }
    return (const uint8_t *)(XIP_BASE + FLASH_STORE_OFFSET + sector * FLASH_SECTOR_SIZE);
}

bool platform_flash_erase(unsigned sector) {
    if (sector >= PLATFORM_FLASH_SECTORS) {
        return false;
    }
    struct flash_job job = {.offset = FLASH_STORE_OFFSET + sector * FLASH_SECTOR_SIZE, .page = NULL};
    if (!flash_job_execute(&job)) {
        return false;
    }
    const uint8_t *stored = platform_flash_sector(sector);
    for (size_t i = 0; i < FLASH_SECTOR_SIZE; i++) {
        if (stored[i] != 0xff) {
            return false;
        }
    }
    return true;
}

bool platform_flash_program(unsigned sector, uint32_t offset, const uint8_t *page) {
    if (sector >= PLATFORM_FLASH_SECTORS || offset % FLASH_PAGE_SIZE != 0
            || offset >= FLASH_SECTOR_SIZE) {
        return false;
    }
    for (size_t i = 0; i < FLASH_PAGE_SIZE; i++) {
        page_buffer[i] = page[i];
    }
    struct flash_job job = {
        .offset = FLASH_STORE_OFFSET + sector * FLASH_SECTOR_SIZE + offset, .page = page_buffer};
    if (!flash_job_execute(&job)) {
        return false;
    }
    /* programming only clears bits: a page that was not erased reads back different */
    const uint8_t *stored = platform_flash_sector(sector) + offset;
    for (size_t i = 0; i < FLASH_PAGE_SIZE; i++) {
        if (stored[i] != page_buffer[i]) {
            return false;
        }
    }
    return true;
}
