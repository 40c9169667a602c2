/* The flash variables (device/flash.py): the device name, the default control mode and a
 * count of writes, kept through power cycles in the platform's two flash sectors.
 *
 * Each write appends one record, one flash page, to the sector in use: a sequence number
 * (the write count), the variables and a CRC-32. The newest valid record wins. When the
 * sector in use is full the other one is erased and the record goes to its first page, so
 * the newest record is never erased while its successor is written: a power cut at any
 * point leaves the old value or the new one. Blank flash (no valid record) is the default
 * name, mode 1 and the simulated motor. */
#ifndef USBMOTION_FLASHVARS_H
#define USBMOTION_FLASHVARS_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include "table.h"

typedef struct {
    char name[TABLE_DEVICE_NAME_MAX + 1]; /* NUL-terminated; "" when erased */
    uint8_t name_length;
    uint8_t default_control_mode;         /* 1..3 */
    uint8_t motor;                        /* call 39: 0 simulated, 1 on the pins */
    uint32_t writes;                      /* every write since the flash was new */
} flash_vars_t;

/* The contents now: the newest valid record, or blank flash's. */
void flashvars_load(flash_vars_t *vars);

/* The name the device answers to: the stored one, or the default when erased. */
const char *flashvars_device_name(const flash_vars_t *vars);

/* Write `next` (its name and mode; the write count is the old one plus one) as a new
 * record. On success *vars becomes the new contents; on failure *vars is unchanged, the
 * old record still holds, and *reason says what failed. */
bool flashvars_store(flash_vars_t *vars, const char *name, uint8_t name_length,
                     uint8_t default_control_mode, uint8_t motor, const char **reason);

/* The CRC-32 of zlib (IEEE 802.3), continued from `crc` (0 to start). */
uint32_t crc32_update(uint32_t crc, const uint8_t *data, size_t length);

#endif
