/* core0: the command interpreter (device/core0.py with protocol/codec.py's LineSplitter and
 * parse_call). Bytes in, lines out through platform_write; the servo state it reads and
 * changes is core1's, always under the servo lock. device.h is its outside. */
#ifndef USBMOTION_INTERP_H
#define USBMOTION_INTERP_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include "table.h"

/* LineSplitter: bytes are buffered until a newline; a line longer than
 * TABLE_MAX_LINE_BYTES (after its trailing carriage returns are dropped, and at most one
 * byte more before they are) is discarded up to its newline and reported once. */
typedef struct {
    uint8_t buffer[TABLE_MAX_LINE_BYTES + 1];
    uint32_t length;
    bool discarding;
} line_splitter_t;

typedef enum {
    SPLIT_NONE,     /* the byte did not end a line */
    SPLIT_LINE,     /* a line is in buffer[0 .. length - 1] (without its \r\n) */
    SPLIT_OVERLONG, /* a line was too long: answer ERR ? line longer than ... */
} split_result_t;

void splitter_reset(line_splitter_t *splitter);
/* Take one byte. After SPLIT_LINE the caller uses the line, then calls splitter_consumed. */
split_result_t splitter_byte(line_splitter_t *splitter, uint8_t byte);
void splitter_consumed(line_splitter_t *splitter);

/* An integer input as _to_int reads it: its value, or for one of more than
 * TABLE_HUGE_DIGITS significant digits (a HugeInteger) +-10^18 and where its digits are in
 * the line, for the message that abbreviates them. */
typedef struct {
    int64_t value;
    const uint8_t *digits; /* the first significant digit (huge only) */
    uint32_t digit_count;  /* significant digits (huge only) */
    bool huge;
} number_t;

/* A parsed and checked call (codec.Call): the call number, its inputs as int64 (every
 * input of a valid call is within int32), and for a counted call its items in
 * interp_items[0 .. item_count - 1]. */
typedef struct {
    uint32_t number;
    uint32_t arg_count;
    int64_t args[TABLE_MAX_PARAMS];
    uint32_t item_count;
    bool is_query;
} call_t;

/* The items of the last counted call parsed (the values of call 1, the characters of
 * call 18). */
extern int32_t interp_items[TABLE_QUEUE_CAPACITY];

typedef enum {
    PARSE_OK,
    PARSE_EMPTY, /* no tokens: ignored */
    PARSE_ERROR, /* the ERR line has been printed */
} parse_result_t;

/* parse_call + check_call + format_err: parses line[0 .. length - 1] into *call, or prints
 * the one ERR line the Python device prints for it. */
parse_result_t interp_parse(const uint8_t *line, uint32_t length, call_t *call);

#endif
