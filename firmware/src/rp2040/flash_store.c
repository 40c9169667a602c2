/* The flash variables' sector: the last 4 KiB sector of the flash, read through XIP and
 * rewritten (erase, then program) inside flash_safe_execute while core1 is locked out. */
#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include "hardware/flash.h"
#include "hardware/sync.h"
#include "pico/flash.h"
#include "pico/multicore.h"

#include "platform.h"

#define FLASH_STORE_OFFSET (PICO_FLASH_SIZE_BYTES - FLASH_SECTOR_SIZE)
/* Time core1 has to acknowledge the lockout (it does so between two servo ticks). */
#define FLASH_STORE_TIMEOUT_MS 100

struct flash_store_job {
    const uint8_t *data;
    size_t length;
};

/* RAM: flash_range_program reads its source while XIP is off */
static uint8_t page_buffer[FLASH_PAGE_SIZE];

static void __not_in_flash_func(flash_store_rewrite)(void *param) {
    const struct flash_store_job *job = param;
    flash_range_erase(FLASH_STORE_OFFSET, FLASH_SECTOR_SIZE);
    for (size_t offset = 0; offset < job->length; offset += FLASH_PAGE_SIZE) {
        for (size_t i = 0; i < FLASH_PAGE_SIZE; i++) {
            /* the tail of the last page stays erased */
            page_buffer[i] = offset + i < job->length ? job->data[offset + i] : 0xff;
        }
        flash_range_program(FLASH_STORE_OFFSET + offset, page_buffer, FLASH_PAGE_SIZE);
    }
}

const uint8_t *platform_flash_read(void) {
    return (const uint8_t *)(XIP_BASE + FLASH_STORE_OFFSET);
}

bool platform_flash_write(const uint8_t *page, size_t length) {
    if (length == 0 || length > FLASH_SECTOR_SIZE) {
        return false;
    }
    struct flash_store_job job = {.data = page, .length = length};
    if (multicore_lockout_victim_is_initialized(1)) {
        if (flash_safe_execute(flash_store_rewrite, &job, FLASH_STORE_TIMEOUT_MS) != PICO_OK) {
            return false;
        }
    } else {
        /* core1 still waits in the bootrom for its launch (device_power_up runs before it),
         * where flash_safe_execute refuses: with no other core to lock out, masking this
         * core's interrupts is enough. */
        uint32_t saved = save_and_disable_interrupts();
        flash_store_rewrite(&job);
        restore_interrupts(saved);
    }
    const uint8_t *stored = platform_flash_read();
    for (size_t i = 0; i < length; i++) {
        if (stored[i] != page[i]) {
            return false;
        }
    }
    return true;
}
