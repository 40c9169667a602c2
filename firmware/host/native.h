/* The native platform (platform_native.c): platform.h on a PC, for the session driver and
 * the tests. The motion queue is a plain ring, the servo lock a checked no-op (taking it
 * twice, releasing it unheld, writing output or clearing the queue in the wrong state abort
 * the program), flash two sectors in memory, output handed to native_output. */
#ifndef USBMOTION_NATIVE_H
#define USBMOTION_NATIVE_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

/* Where platform_write's bytes go: defined by the program linking the platform. */
void native_output(const char *bytes, size_t length);

/* Flash: blank (all 0xff), or loaded from / saved to a file of the two sectors' bytes. */
void native_flash_blank(void);
bool native_flash_load(const char *path);  /* false: unreadable (a missing file is blank) */
bool native_flash_save(const char *path);
/* The next erase or program stops after `bytes` bytes and fails, as a power cut or a worn
 * page would leave it. */
void native_flash_fail_next(uint32_t bytes);
/* Erases and page programs since the flash was blank. */
uint32_t native_flash_erases(void);
uint32_t native_flash_programs(void);

/* The period the device last asked for (platform_servo_period_changed), 0 before. */
uint32_t native_servo_period_us(void);

#endif
