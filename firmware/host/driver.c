/* The session driver: replays a session on the portable device code with the native
 * platform, as the emulator harness replays it on the chip.
 *
 *     usbmotion_native [--flash FILE] < session
 *
 * The session is one command per line:
 *     feed HEX       bytes from USB (hex, any length, may be empty)
 *     run N          N servo ticks (each followed by core0's poll of the records)
 *     power          a power cycle: RAM defaults, flash kept
 *     flash-fail K   the next flash erase or program stops after K bytes and fails
 * Every line the device prints is written as `TICK HEX`, TICK the servo ticks run since
 * the session started (never zeroed, across power cycles) when the line was printed; a last
 * line without its newline ends in ` -`. With --flash the flash is read from FILE (missing:
 * blank) and written back at the end. */
#define _POSIX_C_SOURCE 200809L

#include <inttypes.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "device.h"
#include "native.h"

static uint64_t ticks;

/* The line being printed and the tick it started at. */
static char *line;
static size_t line_length;
static size_t line_capacity;
static uint64_t line_tick;

static void emit(bool ended) {
    printf("%" PRIu64 " ", line_tick);
    for (size_t i = 0; i < line_length; i++) {
        printf("%02x", (unsigned char)line[i]);
    }
    fputs(ended ? "\n" : " -\n", stdout);
    line_length = 0;
}

void native_output(const char *bytes, size_t length) {
    for (size_t i = 0; i < length; i++) {
        if (line_length == 0) {
            line_tick = ticks;
        }
        if (bytes[i] == '\n') {
            emit(true);
            continue;
        }
        if (line_length == line_capacity) {
            line_capacity = line_capacity ? 2 * line_capacity : 4096;
            line = realloc(line, line_capacity);
            if (line == NULL) {
                fputs("out of memory\n", stderr);
                exit(2);
            }
        }
        line[line_length++] = bytes[i];
    }
}

static int hex_value(char c) {
    if (c >= '0' && c <= '9') {
        return c - '0';
    }
    if (c >= 'a' && c <= 'f') {
        return c - 'a' + 10;
    }
    if (c >= 'A' && c <= 'F') {
        return c - 'A' + 10;
    }
    return -1;
}

static void fail(const char *what, const char *command) {
    fprintf(stderr, "session: %s: %s\n", what, command);
    exit(2);
}

static void feed(char *hex, const char *command) {
    size_t length = strlen(hex);
    if (length % 2 != 0) {
        fail("odd number of hex digits", command);
    }
    uint8_t *bytes = (uint8_t *)hex; /* decoded in place */
    for (size_t i = 0; i < length / 2; i++) {
        int high = hex_value(hex[2 * i]);
        int low = hex_value(hex[2 * i + 1]);
        if (high < 0 || low < 0) {
            fail("not hex", command);
        }
        bytes[i] = (uint8_t)(high * 16 + low);
    }
    device_feed(bytes, length / 2);
}

static uint64_t count(const char *text, const char *command) {
    char *end;
    unsigned long long value = strtoull(text, &end, 10);
    if (end == text || *end != '\0') {
        fail("not a count", command);
    }
    return (uint64_t)value;
}

int main(int argc, char **argv) {
    const char *flash_path = NULL;
    if (argc == 3 && strcmp(argv[1], "--flash") == 0) {
        flash_path = argv[2];
    } else if (argc != 1) {
        fputs("usage: usbmotion_native [--flash FILE] < session\n", stderr);
        return 2;
    }
    if (flash_path != NULL) {
        if (!native_flash_load(flash_path)) {
            fprintf(stderr, "flash file %s is not two sectors of flash\n", flash_path);
            return 2;
        }
    } else {
        native_flash_blank();
    }
    device_power_up();

    char *command = NULL;
    size_t capacity = 0;
    ssize_t read;
    while ((read = getline(&command, &capacity, stdin)) >= 0) {
        while (read > 0 && (command[read - 1] == '\n' || command[read - 1] == '\r')) {
            command[--read] = '\0';
        }
        if (strncmp(command, "feed", 4) == 0 && (command[4] == ' ' || command[4] == '\0')) {
            feed(command + (command[4] == ' ' ? 5 : 4), command);
        } else if (strncmp(command, "run ", 4) == 0) {
            uint64_t n = count(command + 4, command);
            for (uint64_t i = 0; i < n; i++) {
                device_servo_tick();
                ticks++;
                device_poll();
            }
        } else if (strcmp(command, "power") == 0) {
            device_power_up();
        } else if (strncmp(command, "flash-fail ", 11) == 0) {
            native_flash_fail_next((uint32_t)count(command + 11, command));
        } else if (read > 0) {
            fail("unknown command", command);
        }
    }
    free(command);
    if (line_length > 0) {
        emit(false);
    }
    free(line);
    if (flash_path != NULL && !native_flash_save(flash_path)) {
        fprintf(stderr, "flash file %s could not be written\n", flash_path);
        return 2;
    }
    return fflush(stdout) == 0 ? 0 : 2;
}
