/* The flash variables: records appended a page at a time, the newest valid one wins. */
#include "flashvars.h"

#include <string.h>

#include "platform.h"

#define PAGES_PER_SECTOR (PLATFORM_FLASH_SECTOR_BYTES / PLATFORM_FLASH_PAGE_BYTES)

/* A record's bytes, little-endian, in the first RECORD_BYTES of its page (the rest 0xff). */
#define RECORD_MAGIC 0x31464d55u /* "UMF1" */
#define AT_MAGIC 0u
#define AT_SEQUENCE 4u           /* the write count: higher is newer */
#define AT_MODE 8u
#define AT_NAME_LENGTH 9u
#define AT_NAME 10u
#define AT_MOTOR 35u             /* call 39; the name's spare byte, 0 in records before it */
#define AT_CRC 36u               /* CRC-32 of bytes 0 .. AT_CRC - 1 */
#define RECORD_BYTES 40u

_Static_assert(AT_NAME + TABLE_DEVICE_NAME_MAX <= AT_MOTOR, "the name fits its record");
_Static_assert(RECORD_BYTES <= PLATFORM_FLASH_PAGE_BYTES, "a record fits a page");

static const uint32_t crc_nibbles[16] = {
    0x00000000u, 0x1db71064u, 0x3b6e20c8u, 0x26d930acu, 0x76dc4190u, 0x6b6b51f4u,
    0x4db26158u, 0x5005713cu, 0xedb88320u, 0xf00f9344u, 0xd6d6a3e8u, 0xcb61b38cu,
    0x9b64c2b0u, 0x86d3d2d4u, 0xa00ae278u, 0xbdbdf21cu,
};

uint32_t crc32_update(uint32_t crc, const uint8_t *data, size_t length) {
    crc = ~crc;
    for (size_t i = 0; i < length; i++) {
        crc ^= data[i];
        crc = (crc >> 4) ^ crc_nibbles[crc & 0xfu];
        crc = (crc >> 4) ^ crc_nibbles[crc & 0xfu];
    }
    return ~crc;
}

static uint32_t read_u32(const uint8_t *bytes) {
    return (uint32_t)bytes[0] | (uint32_t)bytes[1] << 8 | (uint32_t)bytes[2] << 16 |
           (uint32_t)bytes[3] << 24;
}

static void write_u32(uint8_t *bytes, uint32_t value) {
    for (unsigned i = 0; i < 4; i++) {
        bytes[i] = (uint8_t)(value >> (8 * i));
    }
}

static const uint8_t *page_at(unsigned sector, unsigned page) {
    return platform_flash_sector(sector) + page * PLATFORM_FLASH_PAGE_BYTES;
}

static bool page_blank(const uint8_t *page) {
    for (unsigned i = 0; i < PLATFORM_FLASH_PAGE_BYTES; i++) {
        if (page[i] != 0xffu) {
            return false;
        }
    }
    return true;
}

/* Reads the record of a page into *vars; false when the page holds no valid record. */
static bool record_read(const uint8_t *page, flash_vars_t *vars) {
    if (read_u32(page + AT_MAGIC) != RECORD_MAGIC ||
        read_u32(page + AT_CRC) != crc32_update(0, page, AT_CRC)) {
        return false;
    }
    uint8_t mode = page[AT_MODE];
    uint8_t length = page[AT_NAME_LENGTH];
    uint8_t motor = page[AT_MOTOR];
    if (mode < 1 || mode > 3 || length > TABLE_DEVICE_NAME_MAX || motor > 1) {
        return false;
    }
    for (unsigned i = 0; i < length; i++) {
        if (page[AT_NAME + i] < 32 || page[AT_NAME + i] > 126) {
            return false;
        }
    }
    memcpy(vars->name, page + AT_NAME, length);
    vars->name[length] = '\0';
    vars->name_length = length;
    vars->default_control_mode = mode;
    vars->motor = motor;
    vars->writes = read_u32(page + AT_SEQUENCE);
    return true;
}

/* The newest valid record (false: none) and the sector it is in. */
static bool newest_record(flash_vars_t *vars, unsigned *sector) {
    bool found = false;
    for (unsigned s = 0; s < PLATFORM_FLASH_SECTORS; s++) {
        for (unsigned p = 0; p < PAGES_PER_SECTOR; p++) {
            flash_vars_t candidate;
            if (record_read(page_at(s, p), &candidate) &&
                (!found || candidate.writes > vars->writes)) {
                *vars = candidate;
                *sector = s;
                found = true;
            }
        }
    }
    return found;
}

void flashvars_load(flash_vars_t *vars) {
    unsigned sector = 0;
    if (!newest_record(vars, &sector)) {
        memset(vars, 0, sizeof *vars);
        vars->default_control_mode = 1;
    }
}

const char *flashvars_device_name(const flash_vars_t *vars) {
    return vars->name_length > 0 ? vars->name : TABLE_DEFAULT_DEVICE_NAME;
}

bool flashvars_store(flash_vars_t *vars, const char *name, uint8_t name_length,
                     uint8_t default_control_mode, uint8_t motor, const char **reason) {
    flash_vars_t next;
    memset(&next, 0, sizeof next);
    memcpy(next.name, name, name_length);
    next.name_length = name_length;
    next.default_control_mode = default_control_mode;
    next.motor = motor;
    next.writes = vars->writes + 1;

    uint8_t page[PLATFORM_FLASH_PAGE_BYTES];
    memset(page, 0xff, sizeof page);
    write_u32(page + AT_MAGIC, RECORD_MAGIC);
    write_u32(page + AT_SEQUENCE, next.writes);
    page[AT_MODE] = default_control_mode;
    page[AT_NAME_LENGTH] = name_length;
    memset(page + AT_NAME, 0, AT_CRC - AT_NAME);
    memcpy(page + AT_NAME, name, name_length);
    page[AT_MOTOR] = motor;
    write_u32(page + AT_CRC, crc32_update(0, page, AT_CRC));

    /* The sector in use: the newest record's (sector 0 on blank flash). The record goes to
     * the page after its last written page, else to the other sector, erased first. */
    flash_vars_t newest;
    unsigned sector = 0;
    (void)newest_record(&newest, &sector);
    unsigned next_page = 0;
    for (unsigned p = PAGES_PER_SECTOR; p > 0; p--) {
        if (!page_blank(page_at(sector, p - 1))) {
            next_page = p;
            break;
        }
    }
    if (next_page == PAGES_PER_SECTOR) {
        sector = (sector + 1) % PLATFORM_FLASH_SECTORS;
        next_page = 0;
        if (!platform_flash_erase(sector)) {
            *reason = "erasing the spare flash sector failed";
            return false;
        }
    }
    if (!platform_flash_program(sector, next_page * PLATFORM_FLASH_PAGE_BYTES, page)) {
        *reason = "programming the flash page failed";
        return false;
    }
    if (memcmp(page_at(sector, next_page), page, sizeof page) != 0) {
        *reason = "the flash page reads back other than written";
        return false;
    }
    *vars = next;
    return true;
}
