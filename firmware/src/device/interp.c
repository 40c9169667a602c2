/* core0: the line splitter, the parser, every call of the table and the device's output,
 * answering byte for byte as src/usbmotion/device/core0.py with protocol/codec.py. */
#include "interp.h"

#include <string.h>

#include "device.h"
#include "flashvars.h"
#include "platform.h"
#include "servo.h"
#include "stepper.h"

_Static_assert(TABLE_QUEUE_CAPACITY == MOTION_QUEUE_CAPACITY, "one queue capacity");
_Static_assert(TABLE_CURVE_BUFFER_CAPACITY == CURVE_BUFFER_CAPACITY, "one keyframe capacity");
_Static_assert(TABLE_MAX_PARAMS >= 4, "call 25 has four inputs");
_Static_assert(TABLE_OUTPUT_COUNT == OUTPUT_COUNT, "one output count");
_Static_assert(TABLE_OUTPUT_QUEUE_CAPACITY == OUTPUT_QUEUE_CAPACITY, "one output queue");

#define DEBUG_FLAG_CALLS 64u /* call 8 sets a flag for any call 0..63, defined or not */
#define HUGE_VALUE 1000000000000000000LL /* 10^18: HugeInteger's value */

/* --- the device: core0's variables and what core1 runs on -------------------------------- */

static servo_state_t servo_state; /* core1's: read and changed only under the servo lock */
static servo_params_t servo_params;
static servo_params_t derived;    /* servo_params_derive's output, copied in under the lock */
static record_ring_t records;
static device_vars_t vars;        /* the RAM variables */
static flash_vars_t flash;
static uint8_t debug_flags[DEBUG_FLAG_CALLS];
static line_splitter_t splitter;
int32_t interp_items[TABLE_QUEUE_CAPACITY];

/* --- output ------------------------------------------------------------------------------ */

#define OUT_BYTES 128u
static char out_buffer[OUT_BYTES];
static size_t out_length;

static void out_flush(void) {
    if (out_length > 0) {
        platform_write(out_buffer, out_length);
        out_length = 0;
    }
}

static void out_char(char c) {
    if (out_length == OUT_BYTES) {
        out_flush();
    }
    out_buffer[out_length++] = c;
}

static void out_bytes(const char *bytes, size_t length) {
    for (size_t i = 0; i < length; i++) {
        out_char(bytes[i]);
    }
}

static void out_text(const char *text) {
    out_bytes(text, strlen(text));
}

/* Python's str(int). */
static size_t format_int(char *into, int64_t value) {
    char digits[20];
    size_t count = 0;
    uint64_t magnitude = value < 0 ? 0u - (uint64_t)value : (uint64_t)value;
    do {
        digits[count++] = (char)('0' + magnitude % 10u);
        magnitude /= 10u;
    } while (magnitude != 0);
    size_t length = 0;
    if (value < 0) {
        into[length++] = '-';
    }
    while (count > 0) {
        into[length++] = digits[--count];
    }
    return length;
}

static void out_int(int64_t value) {
    char text[21];
    out_bytes(text, format_int(text, value));
}

static void out_end_line(void) {
    out_char('\n');
    out_flush();
}

/* A field of a template: one integer, a text, or a list of values (the rest of the line). */
typedef struct {
    int64_t number;
    const char *text;      /* a text field when not NULL */
    const int32_t *values; /* a list of values when not NULL */
    uint32_t count;
} field_t;

#define NUMBER(x) ((field_t){.number = (x)})
#define TEXT(t) ((field_t){.text = (t)})
#define VALUES(v, n) ((field_t){.values = (v), .count = (n)})

/* Template.format: the literal text with each {field} replaced, in order, then the newline. */
static void print_template(const template_t *template, const field_t *fields) {
    unsigned index = 0;
    for (const char *c = template->text; *c != '\0'; c++) {
        if (*c != '{') {
            out_char(*c);
            continue;
        }
        while (*c != '}') {
            c++;
        }
        const field_t *field = &fields[index++];
        if (field->text != NULL) {
            out_text(field->text);
        } else if (field->values != NULL) {
            for (uint32_t i = 0; i < field->count; i++) {
                if (i > 0) {
                    out_char(' ');
                }
                out_int(field->values[i]);
            }
        } else {
            out_int(field->number);
        }
    }
    out_end_line();
}

static void print_plain(const char *line) {
    out_text(line);
    out_end_line();
}

/* _reply: the query reply of the call. */
static void reply(uint32_t number, const field_t *fields) {
    print_template(&call_table[number].query_reply, fields);
}

/* _debug_line: the call's debug line, when its flag has one (undefined flags act as 0). */
static void debug_line(uint32_t number, const field_t *fields) {
    uint8_t flag = debug_flags[number];
    if (flag <= TABLE_MAX_DEBUG_FLAG && call_table[number].debug[flag].text != NULL) {
        print_template(&call_table[number].debug[flag], fields);
    }
}

/* --- messages: short texts built before an ERR line is printed ---------------------------- */

typedef struct {
    char text[256];
    size_t length;
} message_t;

static void message_char(message_t *m, char c) {
    if (m->length + 1 < sizeof m->text) {
        m->text[m->length++] = c;
        m->text[m->length] = '\0';
    }
}

static void message_text(message_t *m, const char *text) {
    while (*text != '\0') {
        message_char(m, *text++);
    }
}

static void message_int(message_t *m, int64_t value) {
    char text[21];
    size_t length = format_int(text, value);
    for (size_t i = 0; i < length; i++) {
        message_char(m, text[i]);
    }
}

/* repr() of an integer input: its value, or HugeInteger's abbreviation
 * `123456789012345678...(40 digits)`. */
static void message_number(message_t *m, const number_t *number) {
    if (!number->huge) {
        message_int(m, number->value);
        return;
    }
    if (number->value < 0) {
        message_char(m, '-');
    }
    for (unsigned i = 0; i < TABLE_HUGE_DIGITS; i++) {
        message_char(m, (char)number->digits[i]);
    }
    message_text(m, "...(");
    message_int(m, number->digit_count);
    message_text(m, " digits)");
}

/* ERR.format(call, reason), `call` being "?" when NULL. */
static void print_err(const char *call, const char *reason) {
    field_t fields[2] = {TEXT(call != NULL ? call : "?"), TEXT(reason)};
    print_template(&template_err, fields);
}

static void print_err_call(uint32_t number, const char *reason) {
    char call[21];
    call[format_int(call, number)] = '\0';
    print_err(call, reason);
}

/* --- LineSplitter ------------------------------------------------------------------------ */

void splitter_reset(line_splitter_t *s) {
    s->length = 0;
    s->discarding = false;
}

split_result_t splitter_byte(line_splitter_t *s, uint8_t byte) {
    if (byte != '\n') {
        if (s->discarding) {
            return SPLIT_NONE;
        }
        if (s->length == sizeof s->buffer) {
            /* a line past TABLE_MAX_LINE_BYTES + 1 bytes can never be short enough */
            s->discarding = true;
            s->length = 0;
            return SPLIT_NONE;
        }
        s->buffer[s->length++] = byte;
        return SPLIT_NONE;
    }
    if (s->discarding) {
        splitter_reset(s);
        return SPLIT_OVERLONG;
    }
    while (s->length > 0 && s->buffer[s->length - 1] == '\r') {
        s->length--;
    }
    if (s->length > TABLE_MAX_LINE_BYTES) {
        splitter_reset(s);
        return SPLIT_OVERLONG;
    }
    return SPLIT_LINE;
}

void splitter_consumed(line_splitter_t *s) {
    s->length = 0;
}

/* --- parse_call -------------------------------------------------------------------------- */

/* The separators of str.split() on the ASCII-decoded line (bytes >= 0x80 decode to U+FFFD,
 * which is none). */
static bool is_separator(uint8_t byte) {
    return byte == ' ' || (byte >= 9 && byte <= 13) || (byte >= 28 && byte <= 31);
}

typedef struct {
    const uint8_t *start;
    uint32_t length;
} token_t;

typedef struct {
    const uint8_t *line;
    uint32_t length;
    uint32_t at;
} tokens_t;

static bool next_token(tokens_t *tokens, token_t *token) {
    while (tokens->at < tokens->length && is_separator(tokens->line[tokens->at])) {
        tokens->at++;
    }
    if (tokens->at == tokens->length) {
        return false;
    }
    uint32_t start = tokens->at;
    while (tokens->at < tokens->length && !is_separator(tokens->line[tokens->at])) {
        tokens->at++;
    }
    token->start = tokens->line + start;
    token->length = tokens->at - start;
    return true;
}

/* _to_int: false when the token does not match [+-]?\d+ ; else its value (HugeInteger's for
 * more than TABLE_HUGE_DIGITS significant digits). */
static bool read_number(token_t token, number_t *number) {
    uint32_t at = 0;
    bool negative = false;
    if (token.start[0] == '+' || token.start[0] == '-') {
        negative = token.start[0] == '-';
        at = 1;
    }
    if (at == token.length) {
        return false;
    }
    for (uint32_t i = at; i < token.length; i++) {
        if (token.start[i] < '0' || token.start[i] > '9') {
            return false;
        }
    }
    while (at < token.length && token.start[at] == '0') {
        at++;
    }
    uint32_t digits = token.length - at;
    number->huge = digits > TABLE_HUGE_DIGITS;
    number->digits = token.start + at;
    number->digit_count = digits;
    if (number->huge) {
        number->value = negative ? -HUGE_VALUE : HUGE_VALUE;
        return true;
    }
    int64_t value = 0;
    for (uint32_t i = at; i < token.length; i++) {
        value = value * 10 + (token.start[i] - '0');
    }
    number->value = negative ? -value : value;
    return true;
}

/* repr() of the offending token as the Python prints it: at most 24 characters, else the
 * first 21 and "..."; quotes as repr chooses them; a byte >= 0x80 is U+FFFD, which the
 * output's backslashreplace prints as \ufffd. */
static void message_token(message_t *m, token_t token) {
    bool cut = token.length > 24;
    uint32_t shown = cut ? 21 : token.length;
    bool single = false;
    bool double_ = false;
    for (uint32_t i = 0; i < shown; i++) {
        single = single || token.start[i] == '\'';
        double_ = double_ || token.start[i] == '"';
    }
    char quote = single && !double_ ? '"' : '\'';
    static const char hex[] = "0123456789abcdef";
    message_char(m, quote);
    for (uint32_t i = 0; i < shown; i++) {
        uint8_t c = token.start[i];
        if (c == (uint8_t)quote || c == '\\') {
            message_char(m, '\\');
            message_char(m, (char)c);
        } else if (c == '\t') {
            message_text(m, "\\t");
        } else if (c == '\n') {
            message_text(m, "\\n");
        } else if (c == '\r') {
            message_text(m, "\\r");
        } else if (c < 0x20 || c == 0x7f) {
            message_text(m, "\\x");
            message_char(m, hex[c >> 4]);
            message_char(m, hex[c & 0xfu]);
        } else if (c >= 0x80) {
            message_text(m, "\\ufffd");
        } else {
            message_char(m, (char)c);
        }
    }
    if (cut) {
        message_text(m, "...");
    }
    message_char(m, quote);
}

/* Param.check's message: `name value is out of range min..max`. */
static void print_range_err(uint32_t call, const param_spec_t *param, const number_t *value) {
    message_t m = {.length = 0};
    message_text(&m, param->name);
    message_char(&m, ' ');
    message_number(&m, value);
    message_text(&m, " is out of range ");
    message_int(&m, param->minimum);
    message_text(&m, "..");
    message_int(&m, param->maximum);
    print_err_call(call, m.text);
}

static bool in_range(const param_spec_t *param, const number_t *value) {
    return value->value >= param->minimum && value->value <= param->maximum;
}

/* CallSpec.is_query */
static bool is_query(const call_spec_t *spec, const number_t *args, uint32_t count) {
    if (spec->query_count == 0 || count != spec->query_count) {
        return false;
    }
    for (unsigned i = 0; i < count; i++) {
        if (!(spec->query_any & (1u << i)) && args[i].value != spec->query[i]) {
            return false;
        }
    }
    return true;
}

/* The items of a counted call, checked in order (CallSpec.problem's last step) and kept in
 * interp_items. The line's integers were all read once already. */
static bool read_items(const uint8_t *line, uint32_t length, uint32_t number,
                       const call_spec_t *spec, uint32_t skip, uint32_t count) {
    tokens_t tokens = {line, length, 0};
    token_t token;
    for (uint32_t i = 0; i < skip; i++) {
        (void)next_token(&tokens, &token);
    }
    for (uint32_t i = 0; i < count; i++) {
        number_t item;
        (void)next_token(&tokens, &token);
        (void)read_number(token, &item);
        if (!in_range(&spec->item, &item)) {
            print_range_err(number, &spec->item, &item);
            return false;
        }
        interp_items[i] = (int32_t)item.value;
    }
    return true;
}

parse_result_t interp_parse(const uint8_t *line, uint32_t length, call_t *call) {
    /* every token an integer (_to_int over the tokens in order) */
    number_t head[1 + TABLE_MAX_PARAMS];
    uint32_t count = 0;
    tokens_t tokens = {line, length, 0};
    token_t token;
    while (next_token(&tokens, &token)) {
        number_t number;
        if (!read_number(token, &number)) {
            message_t m = {.length = 0};
            char call_text[48];
            const char *call_name = NULL;
            if (count == 0) {
                message_text(&m, "executive call ");
            } else {
                message_text(&m, "input ");
                message_int(&m, count);
                message_char(&m, ' ');
                if (!head[0].huge) {
                    call_text[format_int(call_text, head[0].value)] = '\0';
                    call_name = call_text;
                }
            }
            message_token(&m, token);
            message_text(&m, " is not an integer");
            print_err(call_name, m.text);
            return PARSE_ERROR;
        }
        if (count < 1 + TABLE_MAX_PARAMS) {
            head[count] = number;
        }
        count++;
    }
    if (count == 0) {
        return PARSE_EMPTY;
    }

    /* check_call */
    const number_t *number = &head[0];
    if (number->huge || number->value < 0 || number->value >= (int64_t)TABLE_CALLS) {
        if (number->huge) {
            print_err(NULL, "unknown call");
        } else {
            char call_text[21];
            call_text[format_int(call_text, number->value)] = '\0';
            print_err(call_text, "unknown call");
        }
        return PARSE_ERROR;
    }
    uint32_t n = (uint32_t)number->value;
    const call_spec_t *spec = &call_table[n];
    const number_t *args = &head[1];
    uint32_t arg_count = count - 1;
    call->number = n;
    call->arg_count = arg_count;
    call->item_count = 0;
    call->is_query = is_query(spec, args, arg_count);
    for (unsigned i = 0; i < TABLE_MAX_PARAMS; i++) {
        call->args[i] = i < arg_count ? args[i].value : 0;
    }

    /* CallSpec.problem */
    if (call->is_query) {
        for (unsigned i = 0; i < arg_count; i++) {
            if ((spec->query_any & (1u << i)) && !in_range(&spec->params[i], &args[i])) {
                print_range_err(n, &spec->params[i], &args[i]);
                return PARSE_ERROR;
            }
        }
        return PARSE_OK;
    }
    if (spec->counted) {
        uint32_t lead = spec->param_count - 1u;
        if (arg_count <= lead) {
            print_err_call(n, "wrong number of inputs");
            return PARSE_ERROR;
        }
        for (unsigned i = 0; i <= lead; i++) {
            if (!in_range(&spec->params[i], &args[i])) {
                print_range_err(n, &spec->params[i], &args[i]);
                return PARSE_ERROR;
            }
        }
        uint32_t items = (uint32_t)args[lead].value;
        if (arg_count != lead + 1u + items) {
            print_err_call(n, "wrong number of inputs");
            return PARSE_ERROR;
        }
        if (!read_items(line, length, n, spec, 1u + lead + 1u, items)) {
            return PARSE_ERROR;
        }
        call->item_count = items;
        return PARSE_OK;
    }
    if (arg_count != spec->param_count) {
        print_err_call(n, "wrong number of inputs");
        return PARSE_ERROR;
    }
    for (unsigned i = 0; i < arg_count; i++) {
        if (!in_range(&spec->params[i], &args[i])) {
            print_range_err(n, &spec->params[i], &args[i]);
            return PARSE_ERROR;
        }
    }
    return PARSE_OK;
}

/* --- core0: copying variables into core1 ------------------------------------------------- */

/* _copy_in, in two halves: derive the params from the RAM variables (soft floating point,
 * outside the lock), then copy them in with the servo lock held (core1 stops, copies,
 * resumes) together with the state changes of the same call. */
static void derive(void) {
    servo_params_derive(&vars, &derived);
}

static void copy_in_locked(void) {
    servo_params = derived;
}

static void set_and_copy_in(void) {
    derive();
    platform_servo_lock();
    copy_in_locked();
    platform_servo_unlock();
}

/* --- core0: shared actions (the servo lock held) ----------------------------------------- */

static void clear_queue_locked(void) {
    mq_clear();
}

static void clear_curve_locked(void) {
    curve_clear(&servo_state.curve);
}

/* _reset_controller: the PID afresh from where the shaft is. */
static void reset_controller_locked(void) {
    servo_state.integral = 0;
    servo_state.fresh = 1;
    servo_state.motion_left = 0;
    servo_state.desired = servo_state.actual;
    servo_state.desired_vel = 0;
    servo_state.vel_acc = 0;
    servo_state.desired_prev = servo_state.actual;
    curve_interrupt(&servo_state.curve);
}

/* _shift_position: calls 23 and 37. */
static void shift_position_locked(int64_t shift) {
    servo_shift_position(&servo_state, shift);
    clear_queue_locked();
    clear_curve_locked();
}

/* The tick runs the simulated motor (or stepper): no motor on the pins (call 39). */
static bool simulated_motor(void) {
    return !servo_params.motor_pins;
}

/* true (with the ERR line printed) when the device is in curve mode: calls 0 and 1. */
static bool refused_in_curve_mode(uint32_t number) {
    platform_servo_lock();
    int32_t mode = servo_state.mode;
    platform_servo_unlock();
    if (mode == MODE_CURVE) {
        print_err_call(number, "curve mode (3) plays keyframes (call 25), not queue values;"
                               " change the mode with call 7");
        return true;
    }
    return false;
}

/* The PID output in millivolts, as the diagnostics line prints it: sci_to_int(c, e + 3). */
static int64_t output_mv(sci_t out) {
    out.e += 3;
    return sci_to_int(out);
}

/* The step generator's timing (calls 5 and 46, and power-up): in step-clock periods. */
static void steps_timing(void) {
    platform_steps_timing((uint32_t)stepper_cycles(vars.pulse_ns),
                          (uint32_t)stepper_cycles(vars.setup_ns),
                          device_tick_us() * STEPPER_CYCLES_PER_US);
}

/* _no_step_fits: true (with the ERR line printed) when a tick of tick_us fits no step pulse
 * of this timing. */
static bool refused_for_no_step(uint32_t number, int64_t tick_us, int64_t pulse_ns,
                                int64_t setup_ns) {
    if (stepper_max_steps_per_tick(tick_us, pulse_ns, setup_ns) >= 1) {
        return false;
    }
    message_t m = {.length = 0};
    message_text(&m, "a ");
    message_int(&m, tick_us);
    message_text(&m, " us tick fits no step pulse of ");
    message_int(&m, pulse_ns);
    message_text(&m, " ns after a ");
    message_int(&m, setup_ns);
    message_text(&m, " ns set-up (call 46)");
    print_err_call(number, m.text);
    return true;
}

/* --- the calls --------------------------------------------------------------------------- */

/* One handler per call, call_<name> for CALL_<NAME> of table.h (the table's names in lower
 * case); the handler table is built from TABLE_CALL_LIST, so a call without one does not
 * compile. */
typedef void (*handler_t)(const call_t *call);

static void call_add_single(const call_t *call) {
    if (refused_in_curve_mode(CALL_ADD_SINGLE)) {
        return;
    }
    if (!mq_try_add((int32_t)call->args[0])) {
        print_plain(call_table[CALL_ADD_SINGLE].refusal);
        return;
    }
    debug_line(CALL_ADD_SINGLE, (field_t[]){NUMBER(call->args[0])});
}

/* values_crc32: the CRC-32 of values as 32-bit little-endian two's complement integers. */
static uint32_t values_crc32(const int32_t *values, uint32_t count) {
    uint32_t crc = 0;
    for (uint32_t i = 0; i < count; i++) {
        uint32_t value = (uint32_t)values[i];
        uint8_t bytes[4] = {(uint8_t)value, (uint8_t)(value >> 8), (uint8_t)(value >> 16),
                            (uint8_t)(value >> 24)};
        crc = crc32_update(crc, bytes, sizeof bytes);
    }
    return crc;
}

static void call_add_multiple(const call_t *call) {
    if (refused_in_curve_mode(CALL_ADD_MULTIPLE)) {
        return;
    }
    uint32_t count = call->item_count;
    /* core1 only takes values away: once the queue has room for all, every add succeeds */
    if (mq_level() + count > TABLE_QUEUE_CAPACITY) {
        print_plain(call_table[CALL_ADD_MULTIPLE].refusal);
        return;
    }
    for (uint32_t i = 0; i < count; i++) {
        (void)mq_try_add(interp_items[i]);
    }
    uint8_t flag = debug_flags[CALL_ADD_MULTIPLE];
    if (flag == 1) {
        debug_line(CALL_ADD_MULTIPLE, (field_t[]){NUMBER(count), VALUES(interp_items, count)});
    } else if (flag == 2) {
        debug_line(CALL_ADD_MULTIPLE,
                   (field_t[]){NUMBER(count), NUMBER(values_crc32(interp_items, count))});
    }
}

static void call_motion_queue(const call_t *call) {
    (void)call;
    uint32_t queued = mq_level();
    reply(CALL_MOTION_QUEUE, (field_t[]){NUMBER(queued), NUMBER(TABLE_QUEUE_CAPACITY - queued)});
}

static void call_set_servo_enable(const call_t *call) {
    platform_servo_lock();
    int32_t enable = servo_state.enable;
    int32_t fault = servo_state.fault;
    if (call->is_query) {
        platform_servo_unlock();
        reply(CALL_SET_SERVO_ENABLE, (field_t[]){NUMBER(enable)});
        return;
    }
    if (call->args[0] == 1 && enable == 0) {
        if (fault != FAULT_NONE) {
            platform_servo_unlock();
            message_t m = {.length = 0};
            message_text(&m, "fault ");
            message_int(&m, fault);
            message_text(&m, " (");
            message_text(&m, fault_names[fault]);
            message_text(&m, ") is latched; clear it with call 30 before enabling");
            print_err_call(CALL_SET_SERVO_ENABLE, m.text);
            return;
        }
        reset_controller_locked();
        servo_state.enable = 1;
    } else if (call->args[0] == 0) {
        servo_state.enable = 0;
        servo_state.out = (sci_t){0, 0};
    }
    platform_servo_unlock();
    debug_line(CALL_SET_SERVO_ENABLE, (field_t[]){NUMBER(call->args[0])});
}

static void call_clear_motion_queue(const call_t *call) {
    (void)call;
    platform_servo_lock();
    clear_queue_locked();
    platform_servo_unlock();
    debug_line(CALL_CLEAR_MOTION_QUEUE, NULL);
}

static void call_set_servo_update_interval(const call_t *call) {
    if (call->is_query) {
        reply(CALL_SET_SERVO_UPDATE_INTERVAL, (field_t[]){NUMBER(device_tick_us())});
        return;
    }
    if (vars.drive != DRIVE_DC && refused_for_no_step(CALL_SET_SERVO_UPDATE_INTERVAL,
                                                      call->args[0] * 100, vars.pulse_ns,
                                                      vars.setup_ns)) {
        return;
    }
    vars.interval_dms = (int32_t)call->args[0];
    derive();
    platform_servo_lock();
    clear_queue_locked();
    clear_curve_locked();
    servo_state.fresh = 1;
    for (unsigned slot = 0; slot < SERVO_HISTORY_SLOTS; slot++) {
        servo_state.counts[slot] = servo_state.actual;
    }
    servo_state.counts_pos = 0;
    copy_in_locked();
    platform_servo_unlock();
    platform_servo_period_changed(device_tick_us());
    steps_timing();
    debug_line(CALL_SET_SERVO_UPDATE_INTERVAL, (field_t[]){NUMBER(device_tick_us())});
}

static void call_set_motion_update_interval_scalar(const call_t *call) {
    if (call->is_query) {
        reply(CALL_SET_MOTION_UPDATE_INTERVAL_SCALAR, (field_t[]){NUMBER(vars.scalar)});
        return;
    }
    vars.scalar = (int32_t)call->args[0];
    derive();
    platform_servo_lock();
    clear_queue_locked();
    servo_state.motion_left = 0;
    copy_in_locked();
    platform_servo_unlock();
    debug_line(CALL_SET_MOTION_UPDATE_INTERVAL_SCALAR, (field_t[]){NUMBER(vars.scalar)});
}

static void call_set_control_mode(const call_t *call) {
    platform_servo_lock();
    if (call->is_query) {
        int32_t mode = servo_state.mode;
        platform_servo_unlock();
        reply(CALL_SET_CONTROL_MODE, (field_t[]){NUMBER(mode)});
        return;
    }
    clear_queue_locked();
    servo_state.mode = (int32_t)call->args[0];
    servo_state.velocity_mode_us = 0;
    reset_controller_locked();
    clear_curve_locked();
    platform_servo_unlock();
    debug_line(CALL_SET_CONTROL_MODE, (field_t[]){NUMBER(call->args[0])});
}

static void call_set_debug_flag(const call_t *call) {
    uint32_t number = (uint32_t)call->args[0];
    if (call->is_query) {
        reply(CALL_SET_DEBUG_FLAG, (field_t[]){NUMBER(number), NUMBER(debug_flags[number])});
        return;
    }
    debug_flags[number] = (uint8_t)call->args[1];
}

/* Calls 9-17, 32 and 33: a RAM variable the call sets whole, queried back as it was set. */
static void sci_call(const call_t *call, sci_t *variable) {
    uint32_t number = call->number;
    if (call->is_query) {
        reply(number, (field_t[]){NUMBER(variable->c), NUMBER(variable->e)});
        return;
    }
    *variable = (sci_t){(int32_t)call->args[0], (int32_t)call->args[1]};
    set_and_copy_in();
    debug_line(number, (field_t[]){NUMBER(call->args[0]), NUMBER(call->args[1])});
}

static void int_call(const call_t *call, int32_t *variable) {
    uint32_t number = call->number;
    if (call->is_query) {
        reply(number, (field_t[]){NUMBER(*variable)});
        return;
    }
    *variable = (int32_t)call->args[0];
    set_and_copy_in();
    debug_line(number, (field_t[]){NUMBER(call->args[0])});
}

static void call_set_proportional_gain(const call_t *call) { sci_call(call, &vars.kp); }
static void call_set_integral_gain(const call_t *call) { sci_call(call, &vars.ki); }
static void call_set_derivative_gain(const call_t *call) { sci_call(call, &vars.kd); }

static void call_set_sim_update_interval(const call_t *call) {
    int_call(call, &vars.sim_update_interval_dms);
}

static void call_set_sim_source_voltage(const call_t *call) {
    sci_call(call, &vars.source_voltage_v);
}

static void call_set_sim_torque_constant(const call_t *call) {
    sci_call(call, &vars.torque_constant_mnm_per_a);
}

static void call_set_sim_winding_resistance(const call_t *call) {
    sci_call(call, &vars.winding_resistance_ohm);
}

static void call_set_sim_counts_per_revolution(const call_t *call) {
    int_call(call, &vars.counts_per_revolution);
}

static void call_set_sim_inertia(const call_t *call) { sci_call(call, &vars.inertia_kg_m2); }

static void call_set_sim_viscous_friction(const call_t *call) {
    sci_call(call, &vars.viscous_friction_unm_per_rad_s);
}

static void call_set_sim_load_torque(const call_t *call) { sci_call(call, &vars.load_torque_mnm); }

/* _write_flash: the ERR line when the write fails (the value unchanged). */
static bool write_flash(uint32_t number, const char *name, uint8_t name_length, uint8_t mode,
                        uint8_t motor) {
    const char *reason = "";
    if (flashvars_store(&flash, name, name_length, mode, motor, &reason)) {
        return true;
    }
    message_t m = {.length = 0};
    message_text(&m, "flash write failed, value unchanged: ");
    message_text(&m, reason);
    print_err_call(number, m.text);
    return false;
}

static void call_set_device_name(const call_t *call) {
    if (call->is_query) {
        reply(CALL_SET_DEVICE_NAME, (field_t[]){TEXT(flashvars_device_name(&flash))});
        return;
    }
    char name[TABLE_DEVICE_NAME_MAX];
    for (uint32_t i = 0; i < call->item_count; i++) {
        name[i] = (char)interp_items[i];
    }
    if (!write_flash(CALL_SET_DEVICE_NAME, name, (uint8_t)call->item_count,
                     flash.default_control_mode, flash.motor)) {
        return;
    }
    debug_line(CALL_SET_DEVICE_NAME, (field_t[]){TEXT(flashvars_device_name(&flash))});
}

static void call_set_default_control_mode(const call_t *call) {
    if (call->is_query) {
        reply(CALL_SET_DEFAULT_CONTROL_MODE, (field_t[]){NUMBER(flash.default_control_mode)});
        return;
    }
    if (!write_flash(CALL_SET_DEFAULT_CONTROL_MODE, flash.name, flash.name_length,
                     (uint8_t)call->args[0], flash.motor)) {
        return;
    }
    debug_line(CALL_SET_DEFAULT_CONTROL_MODE, (field_t[]){NUMBER(call->args[0])});
}

static void call_set_motor(const call_t *call) {
    if (call->is_query) {
        reply(CALL_SET_MOTOR, (field_t[]){NUMBER(flash.motor), NUMBER(vars.motor_pins)});
        return;
    }
    if (!write_flash(CALL_SET_MOTOR, flash.name, flash.name_length, flash.default_control_mode,
                     (uint8_t)call->args[0])) {
        return;
    }
    debug_line(CALL_SET_MOTOR, (field_t[]){NUMBER(call->args[0])});
}

static void call_status(const call_t *call) {
    (void)call;
    platform_servo_lock();
    const servo_state_t *s = &servo_state;
    field_t fields[9] = {
        NUMBER(s->clock),
        NUMBER(s->actual),
        NUMBER(s->mode == MODE_VELOCITY ? s->desired_vel : s->desired),
        NUMBER(s->velocity),
        NUMBER(s->mode == MODE_CURVE ? curve_queued(&s->curve) : mq_level()),
        NUMBER(s->enable),
        NUMBER(s->mode),
        NUMBER(s->limits),
        NUMBER(s->fault),
    };
    platform_servo_unlock();
    reply(CALL_STATUS, fields);
}

static void call_set_diagnostics_interval(const call_t *call) {
    if (call->is_query) {
        reply(CALL_SET_DIAGNOSTICS_INTERVAL, (field_t[]){NUMBER(vars.diag_n)});
        return;
    }
    vars.diag_n = (int32_t)call->args[0];
    derive();
    platform_servo_lock();
    servo_state.diag_left = vars.diag_n;
    servo_state.diag_peak = 0;
    copy_in_locked();
    platform_servo_unlock();
    debug_line(CALL_SET_DIAGNOSTICS_INTERVAL, (field_t[]){NUMBER(vars.diag_n)});
}

static void call_clock(const call_t *call) {
    platform_servo_lock();
    int64_t clock = servo_state.clock;
    if (!call->is_query) {
        servo_state.clock = 0;
        servo_drop_pending_outputs(&servo_state);   /* their ticks were on the old clock */
    }
    platform_servo_unlock();
    if (call->is_query) {
        reply(CALL_CLOCK, (field_t[]){NUMBER(clock)});
        return;
    }
    debug_line(CALL_CLOCK, NULL);
}

static void call_set_position(const call_t *call) {
    platform_servo_lock();
    shift_position_locked(call->args[0] - servo_state.actual);
    platform_servo_unlock();
    debug_line(CALL_SET_POSITION, (field_t[]){NUMBER(call->args[0])});
}

static void call_limits(const call_t *call) {
    (void)call;
    platform_servo_lock();
    int32_t limits = servo_state.limits;
    platform_servo_unlock();
    reply(CALL_LIMITS, (field_t[]){NUMBER(limits & 1), NUMBER((limits >> 1) & 1)});
}

static void call_append_keyframe(const call_t *call) {
    keyframe_t keyframe = {
        .duration_ms = (uint16_t)call->args[0],
        .position_counts = (int32_t)call->args[1],
        .tangent_in = (int16_t)call->args[2],
        .tangent_out = (int16_t)call->args[3],
    };
    /* its segment derived outside the lock: core1 reads neither the keyframe appended
     * last nor the period, which only core0 writes */
    curve_prepared_t prepared;
    curve_prepare_keyframe(&servo_state.curve, keyframe, servo_params.tick_us, &prepared);
    platform_servo_lock();
    if (servo_state.mode != MODE_CURVE) {
        platform_servo_unlock();
        print_err_call(CALL_APPEND_KEYFRAME,
                       "keyframes play in curve mode only; select it with call 7 3");
        return;
    }
    bool appended = curve_append_prepared(&servo_state.curve, keyframe, &prepared);
    platform_servo_unlock();
    if (!appended) {
        print_plain(call_table[CALL_APPEND_KEYFRAME].refusal);
        return;
    }
    debug_line(CALL_APPEND_KEYFRAME, (field_t[]){NUMBER(call->args[0]), NUMBER(call->args[1]),
                                                 NUMBER(call->args[2]), NUMBER(call->args[3])});
}

static void call_clear_keyframes(const call_t *call) {
    (void)call;
    platform_servo_lock();
    clear_curve_locked();
    platform_servo_unlock();
    debug_line(CALL_CLEAR_KEYFRAMES, NULL);
}

static void call_curve_buffer(const call_t *call) {
    (void)call;
    platform_servo_lock();
    uint32_t queued = curve_queued(&servo_state.curve);
    platform_servo_unlock();
    reply(CALL_CURVE_BUFFER, (field_t[]){NUMBER(TABLE_CURVE_BUFFER_CAPACITY - queued)});
}

static void call_set_watchdog(const call_t *call) { int_call(call, &vars.watchdog_ms); }
static void call_set_following_error_limit(const call_t *call) { int_call(call, &vars.fe_limit); }

static void call_clear_fault(const call_t *call) {
    platform_servo_lock();
    int32_t fault = servo_state.fault;
    int64_t fault_tick = servo_state.fault_tick;
    if (!call->is_query) {
        servo_state.fault = FAULT_NONE;
        servo_state.fault_tick = 0;
    }
    platform_servo_unlock();
    if (call->is_query) {
        reply(CALL_CLEAR_FAULT, (field_t[]){NUMBER(fault), NUMBER(fault_tick)});
        return;
    }
    debug_line(CALL_CLEAR_FAULT, NULL);
}

static void call_start_at(const call_t *call) {
    platform_servo_lock();
    int64_t start = servo_state.start;
    if (!call->is_query) {
        servo_state.start = call->args[0];
    }
    platform_servo_unlock();
    if (call->is_query) {
        reply(CALL_START_AT, (field_t[]){NUMBER(start)});
        return;
    }
    debug_line(CALL_START_AT, (field_t[]){NUMBER(call->args[0])});
}

static void call_set_sim_travel(const call_t *call) {
    if (call->is_query) {
        reply(CALL_SET_SIM_TRAVEL, (field_t[]){NUMBER(vars.travel_lower_counts),
                                               NUMBER(vars.travel_upper_counts)});
        return;
    }
    int64_t lower = call->args[0];
    int64_t upper = call->args[1];
    if (lower >= upper) {
        message_t m = {.length = 0};
        message_text(&m, "lower end ");
        message_int(&m, lower);
        message_text(&m, " must be below upper end ");
        message_int(&m, upper);
        print_err_call(CALL_SET_SIM_TRAVEL, m.text);
        return;
    }
    vars.travel_lower_counts = (int32_t)lower;
    vars.travel_upper_counts = (int32_t)upper;
    derive();
    platform_servo_lock();
    copy_in_locked();
    servo_state.limits = servo_switches(&servo_state, &servo_params);
    platform_servo_unlock();
    debug_line(CALL_SET_SIM_TRAVEL, (field_t[]){NUMBER(lower), NUMBER(upper)});
}

static void call_motion_stats(const call_t *call) {
    platform_servo_lock();
    servo_state_t *s = &servo_state;
    field_t fields[5] = {NUMBER(s->stats_ticks), NUMBER(s->stats_max), NUMBER(s->stats_max_tick),
                         NUMBER(s->stats_sum_sq), NUMBER(s->last_take)};
    if (!call->is_query) {
        s->stats_ticks = 0;
        s->stats_max = 0;
        s->stats_max_tick = 0;
        s->stats_sum_sq = 0;
        s->last_take = -1;
        s->diag_peak = 0;
    }
    platform_servo_unlock();
    if (call->is_query) {
        reply(CALL_MOTION_STATS, fields);
        return;
    }
    debug_line(CALL_MOTION_STATS, NULL);
}

static void call_switch_edge(const call_t *call) {
    uint32_t which = (uint32_t)call->args[0];
    platform_servo_lock();
    switch_edge_t edge = servo_state.edges[which - 1];
    platform_servo_unlock();
    reply(CALL_SWITCH_EDGE, (field_t[]){NUMBER(which), NUMBER(edge.edges), NUMBER(edge.closed),
                                        NUMBER(edge.position), NUMBER(edge.tick)});
}

static void call_shift_position(const call_t *call) {
    platform_servo_lock();
    shift_position_locked(call->args[0]);
    platform_servo_unlock();
    debug_line(CALL_SHIFT_POSITION, (field_t[]){NUMBER(call->args[0])});
}

static void call_set_sim_probe(const call_t *call) {
    if (call->is_query) {
        reply(CALL_SET_SIM_PROBE,
              (field_t[]){NUMBER(vars.probe_side), NUMBER(vars.probe_position)});
        return;
    }
    vars.probe_side = (int32_t)call->args[0];
    vars.probe_position = (int32_t)call->args[1];
    derive();
    platform_servo_lock();
    copy_in_locked();
    if (simulated_motor()) {
        servo_state.probe = servo_probe(&servo_state, &servo_params);   /* no edge */
    }
    platform_servo_unlock();
    debug_line(CALL_SET_SIM_PROBE,
               (field_t[]){NUMBER(vars.probe_side), NUMBER(vars.probe_position)});
}

static void call_probe(const call_t *call) {
    (void)call;
    platform_servo_lock();
    int32_t closed = servo_state.probe;
    switch_edge_t edge = servo_state.probe_edge;
    platform_servo_unlock();
    reply(CALL_PROBE, (field_t[]){NUMBER(closed), NUMBER(edge.edges), NUMBER(edge.closed),
                                  NUMBER(edge.position), NUMBER(edge.tick)});
}

static void call_set_output_at(const call_t *call) {
    int64_t output = call->args[0];
    int64_t value = call->args[1];
    int64_t tick = call->args[2];
    message_t m = {.length = 0};
    output_queue_t *q = &servo_state.outputs;
    platform_servo_lock();
    int32_t fault = servo_state.fault;
    uint32_t pending = servo_pending_outputs(&servo_state);
    output_record_t *last =
        q->records > 0
            ? &q->queue[(q->head + q->records - 1u) % OUTPUT_QUEUE_CAPACITY]
            : 0;
    int64_t last_tick = last ? last->tick : 0;
    if (fault != FAULT_NONE) {
        platform_servo_unlock();
        message_text(&m, "fault ");
        message_int(&m, fault);
        message_text(&m, " (");
        message_text(&m, fault_names[fault]);
        message_text(&m, ") is latched; clear it with call 30 before setting an output");
        print_err_call(CALL_SET_OUTPUT_AT, m.text);
        return;
    }
    if (output < (int64_t)TABLE_DIGITAL_OUTPUTS && value != 0 && value != TABLE_OUTPUT_FULL) {
        platform_servo_unlock();
        message_text(&m, "output ");
        message_int(&m, output);
        message_text(&m, " is digital: value ");
        message_int(&m, value);
        message_text(&m, " must be 0 or ");
        message_int(&m, TABLE_OUTPUT_FULL);
        print_err_call(CALL_SET_OUTPUT_AT, m.text);
        return;
    }
    if (last && tick < last_tick) {
        platform_servo_unlock();
        message_text(&m, "tick ");
        message_int(&m, tick);
        message_text(&m, " is before the last pending change's tick ");
        message_int(&m, last_tick);
        print_err_call(CALL_SET_OUTPUT_AT, m.text);
        return;
    }
    if (pending >= OUTPUT_QUEUE_CAPACITY) {
        platform_servo_unlock();
        print_plain(call_table[CALL_SET_OUTPUT_AT].refusal);
        return;
    }
    /* the outputs once every pending change applied, with this one */
    output_record_t *record = last;
    if (!last || tick != last_tick) {
        record = &q->queue[(q->head + q->records) % OUTPUT_QUEUE_CAPACITY];
        record->values = last ? last->values : q->values;
        record->tick = tick;
        record->changes = 0;
        if (q->records == 0) {
            q->next = tick;
        }
        q->records += 1u;
    }
    record->values.per_mille[output] = (int16_t)value;
    record->changes += 1u;
    platform_outputs_form(record->values.per_mille, &record->pins);
    platform_servo_unlock();
    debug_line(CALL_SET_OUTPUT_AT,
               (field_t[]){NUMBER(output), NUMBER(value), NUMBER(tick),
                           NUMBER(OUTPUT_QUEUE_CAPACITY - pending - 1u)});
}

static void call_outputs(const call_t *call) {
    platform_servo_lock();
    if (call->args[0] == 1) {
        servo_drop_pending_outputs(&servo_state);
    }
    int32_t values[OUTPUT_COUNT];
    for (uint32_t output = 0; output < OUTPUT_COUNT; output++) {
        values[output] = servo_state.outputs.values.per_mille[output];
    }
    uint32_t pending = servo_pending_outputs(&servo_state);
    int64_t last = servo_state.outputs.last;
    platform_servo_unlock();
    reply(CALL_OUTPUTS, (field_t[]){NUMBER(values[0]), NUMBER(values[1]), NUMBER(values[2]),
                                    NUMBER(values[3]), NUMBER(pending), NUMBER(last)});
}

static void call_set_drive(const call_t *call) {
    if (call->is_query) {
        reply(CALL_SET_DRIVE, (field_t[]){NUMBER(vars.drive)});
        return;
    }
    platform_servo_lock();
    int32_t enable = servo_state.enable;
    platform_servo_unlock();
    if (enable == 1) {
        print_err_call(CALL_SET_DRIVE, "the servo is enabled: disable it (call 3 0) before"
                                       " changing what it drives");
        return;
    }
    int32_t drive = (int32_t)call->args[0];
    if (drive != DRIVE_DC && refused_for_no_step(CALL_SET_DRIVE, device_tick_us(),
                                                 vars.pulse_ns, vars.setup_ns)) {
        return;
    }
    vars.drive = drive;
    derive();
    motor_pins_sample_t pins = {0};
    bool on_pins = vars.motor_pins;
    if (on_pins) {
        platform_motor_pins_sample(&pins);
    }
    platform_servo_lock();
    /* a change of motor: the shaft at 0 at rest, the counters at 0, the PID afresh */
    servo_state_t *s = &servo_state;
    s->theta = 0;
    s->omega = 0;
    s->offset = 0;
    s->actual = 0;
    s->velocity = 0;
    s->phase = 0;
    s->last_steps = 0;
    s->desired = 0;
    for (unsigned slot = 0; slot < SERVO_HISTORY_SLOTS; slot++) {
        s->counts[slot] = 0;
    }
    s->counts_pos = 0;
    clear_queue_locked();
    clear_curve_locked();
    reset_controller_locked();
    copy_in_locked();
    if (on_pins) {
        servo_pins_power_up(s, &servo_params, &pins);   /* the counter at 0 where it is */
    } else {
        s->limits = servo_switches(s, &servo_params);
        s->probe = servo_probe(s, &servo_params);
    }
    platform_servo_unlock();
    debug_line(CALL_SET_DRIVE, (field_t[]){NUMBER(drive)});
}

static void call_set_stepper(const call_t *call) {
    if (call->is_query) {
        reply(CALL_SET_STEPPER, (field_t[]){NUMBER(vars.full_steps), NUMBER(vars.microsteps)});
        return;
    }
    vars.full_steps = (int32_t)call->args[0];
    vars.microsteps = (int32_t)call->args[1];
    derive();
    platform_servo_lock();
    clear_queue_locked();
    clear_curve_locked();
    copy_in_locked();
    platform_servo_unlock();
    debug_line(CALL_SET_STEPPER, (field_t[]){NUMBER(call->args[0]), NUMBER(call->args[1])});
}

static void call_set_step_timing(const call_t *call) {
    if (call->is_query) {
        reply(CALL_SET_STEP_TIMING, (field_t[]){NUMBER(vars.pulse_ns), NUMBER(vars.setup_ns)});
        return;
    }
    if (refused_for_no_step(CALL_SET_STEP_TIMING, device_tick_us(), call->args[0],
                            call->args[1])) {
        return;
    }
    vars.pulse_ns = (int32_t)call->args[0];
    vars.setup_ns = (int32_t)call->args[1];
    set_and_copy_in();
    steps_timing();
    debug_line(CALL_SET_STEP_TIMING, (field_t[]){NUMBER(call->args[0]), NUMBER(call->args[1])});
}

static void call_set_sim_stepper(const call_t *call) {
    if (call->is_query) {
        reply(CALL_SET_SIM_STEPPER, (field_t[]){NUMBER(vars.holding_mnm), NUMBER(vars.detent_mnm),
                                                NUMBER(vars.corner_rpm)});
        return;
    }
    int64_t holding = call->args[0];
    int64_t detent = call->args[1];
    if (detent > holding) {
        message_t m = {.length = 0};
        message_text(&m, "detent torque ");
        message_int(&m, detent);
        message_text(&m, " mNm is more than the holding torque ");
        message_int(&m, holding);
        message_text(&m, " mNm");
        print_err_call(CALL_SET_SIM_STEPPER, m.text);
        return;
    }
    vars.holding_mnm = (int32_t)holding;
    vars.detent_mnm = (int32_t)detent;
    vars.corner_rpm = (int32_t)call->args[2];
    set_and_copy_in();
    debug_line(CALL_SET_SIM_STEPPER,
               (field_t[]){NUMBER(holding), NUMBER(detent), NUMBER(call->args[2])});
}

static void call_steps(const call_t *call) {
    (void)call;
    platform_servo_lock();
    int32_t issued = wrap_int32(servo_state.phase);
    int32_t last = servo_state.last_steps;
    platform_servo_unlock();
    reply(CALL_STEPS, (field_t[]){NUMBER(issued), NUMBER(last),
                                  NUMBER(stepper_max_steps_per_tick(device_tick_us(), vars.pulse_ns,
                                                                    vars.setup_ns))});
}

/* Call 49: one turn of the encoder, in counts of the counter. */
static int64_t encoder_turn(void) {
    return vars.drive == DRIVE_STEP_CLOSED ? (int64_t)vars.full_steps * vars.microsteps
                                           : (int64_t)vars.counts_per_revolution;
}

static void call_set_encoder(const call_t *call) {
    if (call->is_query) {
        int64_t zero = 0;
        if (vars.encoder_kind == 1) {
            /* where the turns begin in the counter's coordinates: (offset + base) floored
             * modulo a turn, the base being the source's count at angle 0: the simulated
             * magnet's -angle, or on the pins what the first frame read */
            platform_servo_lock();
            int64_t offset = servo_state.offset;
            int64_t base = -(int64_t)vars.encoder_angle;
            if (vars.motor_pins && servo_state.absenc.have) {
                base = servo_state.absenc.base;
            }
            platform_servo_unlock();
            int64_t turn = encoder_turn();
            zero = (offset + base) % turn;
            if (zero < 0) {
                zero += turn;
            }
        }
        reply(CALL_SET_ENCODER, (field_t[]){NUMBER(vars.encoder_kind),
                                            NUMBER(vars.encoder_angle), NUMBER(zero)});
        return;
    }
    platform_servo_lock();
    int32_t enable = servo_state.enable;
    platform_servo_unlock();
    if (enable == 1) {
        print_err_call(CALL_SET_ENCODER, "the servo is enabled: disable it (call 3 0) before"
                                         " changing its encoder");
        return;
    }
    int32_t kind = (int32_t)call->args[0];
    int32_t angle = (int32_t)call->args[1];
    if (kind == 1 && vars.drive == DRIVE_STEP_OPEN) {
        print_err_call(CALL_SET_ENCODER, "an open-loop stepper (drive 1) counts its steps: it"
                                         " has no encoder to read");
        return;
    }
    vars.encoder_kind = kind;
    vars.encoder_angle = angle;
    if (vars.motor_pins) {
        /* the encoder on the pins: its input changes; an absolute one's first frame makes the
         * counter its angle (core1, servo.c absenc_source); `angle` is the simulated magnet's */
        derive();
        platform_servo_lock();
        copy_in_locked();
        platform_motor_pins_encoder(kind);
        motor_pins_sample_t pins;
        platform_motor_pins_sample(&pins);
        servo_pins_encoder_changed(&servo_state, &servo_params, &pins);
        if (kind == 1) {
            clear_queue_locked();
            clear_curve_locked();
        }
        platform_servo_unlock();
    } else if (kind == 1) {
        /* the counter becomes the angle within a turn: (source + angle) floored modulo it */
        int64_t turn = encoder_turn();
        platform_servo_lock();
        int64_t source = wrap_int32((int64_t)servo_state.actual - servo_state.offset);
        int64_t within = (source + angle) % turn;
        if (within < 0) {
            within += turn;
        }
        shift_position_locked(within - servo_state.actual);
        platform_servo_unlock();
    }
    debug_line(CALL_SET_ENCODER, (field_t[]){NUMBER(kind), NUMBER(angle)});
}

static int64_t ceil_div(int64_t numerator, int64_t denominator) {
    return numerator >= 0 ? (numerator + denominator - 1) / denominator
                          : -((-numerator) / denominator);
}

/* Calls 38 and 50 from device tick `tick`, with the servo lock held: the queued values due
 * before it (kept), and how many value periods the first new value's tick is already past
 * (late; 0 on time). With the servo disabled nothing is due: both 0. */
static void replacement_timing(int64_t tick, int64_t *kept, int64_t *late) {
    *kept = 0;
    *late = 0;
    if (servo_state.enable != 1) {
        return;
    }
    int64_t queued = mq_level();
    int64_t clock = servo_state.clock;
    int64_t start = servo_state.start;
    int64_t first = start >= 0 ? (start > clock ? start : clock) : clock + servo_state.motion_left;
    int64_t ahead = ceil_div(tick - first, vars.scalar);
    int64_t behind = ceil_div(first - tick, vars.scalar);
    *kept = ahead < 0 ? 0 : (ahead < queued ? ahead : queued);
    *late = behind < 0 ? 0 : behind;
}

/* Values call 38 adds with the servo lock still held: the first new values may be due on
 * the next tick; the rest go in after it is released, far faster than core1 takes them. */
#define REPLACE_LOCKED_VALUES 16u

/* Calls 38 and 50, with the servo lock held (released here): the queue keeps its first
 * `kept` values, then takes `count` values each moved by `offset` (checked to fit int32). */
static void keep_then_add_unlocking(uint32_t kept, const int32_t *values, uint32_t count,
                                    int64_t offset) {
    mq_truncate(kept);
    uint32_t locked = count < REPLACE_LOCKED_VALUES ? count : REPLACE_LOCKED_VALUES;
    for (uint32_t i = 0; i < locked; i++) {
        (void)mq_try_add((int32_t)(values[i] + offset));
    }
    platform_servo_unlock();
    for (uint32_t i = locked; i < count; i++) {
        (void)mq_try_add((int32_t)(values[i] + offset));
    }
}

static void call_replace_from(const call_t *call) {
    if (refused_in_curve_mode(CALL_REPLACE_FROM)) {
        return;
    }
    int64_t tick = call->args[0];
    int64_t count = call->args[1];
    platform_servo_lock();
    int64_t kept = 0;
    int64_t late = 0;
    replacement_timing(tick, &kept, &late);
    int64_t skipped = late < count ? late : count;
    uint32_t added = (uint32_t)(count - skipped);
    if (kept + added > TABLE_QUEUE_CAPACITY) {
        platform_servo_unlock();
        print_plain(call_table[CALL_REPLACE_FROM].refusal);
        return;
    }
    const int32_t *values = &interp_items[skipped];
    keep_then_add_unlocking((uint32_t)kept, values, added, 0);
    if (debug_flags[CALL_REPLACE_FROM] == 1) {
        debug_line(CALL_REPLACE_FROM, (field_t[]){NUMBER(kept), NUMBER(skipped), NUMBER(added),
                                                  NUMBER(values_crc32(values, added))});
    }
}

/* Call 50: as call 38 on time; late, every value from the next motion update, offset in
 * mode 1 so that the axis goes on from the value the queue had due then. */
static void call_stop_from(const call_t *call) {
    if (refused_in_curve_mode(CALL_STOP_FROM)) {
        return;
    }
    int64_t tick = call->args[0];
    uint32_t count = (uint32_t)call->args[1];
    const int32_t *values = interp_items;
    platform_servo_lock();
    int64_t kept = 0;
    int64_t late = 0;
    int64_t offset = 0;
    replacement_timing(tick, &kept, &late);
    if (late > 0 && count > 0 && servo_state.mode == MODE_POSITION) {
        int64_t due = mq_level() > 0 ? mq_peek(0) : servo_state.desired;
        offset = due - values[0];
    }
    bool refused = kept + count > TABLE_QUEUE_CAPACITY;
    for (uint32_t i = 0; i < count && offset != 0 && !refused; i++) {
        int64_t moved = (int64_t)values[i] + offset;
        refused = moved < INT32_MIN || moved > INT32_MAX;
    }
    if (refused) {
        platform_servo_unlock();
        print_plain(call_table[CALL_STOP_FROM].refusal);
        return;
    }
    uint32_t crc = debug_flags[CALL_STOP_FROM] == 1 ? values_crc32(values, count) : 0;
    keep_then_add_unlocking((uint32_t)kept, values, count, offset);
    if (debug_flags[CALL_STOP_FROM] == 1) {
        debug_line(CALL_STOP_FROM, (field_t[]){NUMBER(kept), NUMBER(late), NUMBER(count),
                                               NUMBER(offset), NUMBER(crc)});
    }
}

#define HANDLER(NAME, name) [CALL_##NAME] = call_##name,
static const handler_t handlers[TABLE_CALLS] = {TABLE_CALL_LIST(HANDLER)};
#undef HANDLER

/* --- lines ------------------------------------------------------------------------------- */

/* _interpret: one line, at the tick it arrives. */
static void interpret(const uint8_t *line, uint32_t length) {
    call_t call;
    if (interp_parse(line, length, &call) != PARSE_OK) {
        return;
    }
    platform_servo_lock();
    servo_state.since_command_us = 0;
    platform_servo_unlock();
    handlers[call.number](&call);
}

static void print_record(const record_t *record) {
    if (record->kind == RECORD_ALARM) {
        print_template(&template_alarm, (field_t[]){NUMBER(record->fault), NUMBER(record->clock)});
        return;
    }
    print_template(&template_diagnostics,
                   (field_t[]){NUMBER(record->clock), NUMBER(record->desired),
                               NUMBER(record->actual), NUMBER(record->velocity),
                               NUMBER(output_mv(record->out)), NUMBER(record->queued),
                               NUMBER(record->peak)});
}

/* --- device.h ---------------------------------------------------------------------------- */

static void ram_defaults(void) {
    memset(&vars, 0, sizeof vars);
    vars.interval_dms = POWER_UP_INTERVAL_DMS;
    vars.scalar = POWER_UP_SCALAR;
    vars.kp = (sci_t){POWER_UP_KP};
    vars.ki = (sci_t){POWER_UP_KI};
    vars.kd = (sci_t){POWER_UP_KD};
    vars.sim_update_interval_dms = POWER_UP_SIM_UPDATE_INTERVAL_DMS;
    vars.source_voltage_v = (sci_t){POWER_UP_SOURCE_VOLTAGE_V};
    vars.torque_constant_mnm_per_a = (sci_t){POWER_UP_TORQUE_CONSTANT_MNM_PER_A};
    vars.winding_resistance_ohm = (sci_t){POWER_UP_WINDING_RESISTANCE_OHM};
    vars.counts_per_revolution = POWER_UP_COUNTS_PER_REVOLUTION;
    vars.inertia_kg_m2 = (sci_t){POWER_UP_INERTIA_KG_M2};
    vars.viscous_friction_unm_per_rad_s = (sci_t){POWER_UP_VISCOUS_FRICTION_UNM_PER_RAD_S};
    vars.load_torque_mnm = (sci_t){POWER_UP_LOAD_TORQUE_MNM};
    vars.travel_lower_counts = POWER_UP_TRAVEL_LOWER_COUNTS;
    vars.travel_upper_counts = POWER_UP_TRAVEL_UPPER_COUNTS;
    vars.overtravel_counts = POWER_UP_OVERTRAVEL_COUNTS;
    vars.diag_n = 0;
    vars.watchdog_ms = 0;
    vars.fe_limit = 0;
    vars.drive = POWER_UP_DRIVE;
    vars.full_steps = POWER_UP_FULL_STEPS;
    vars.microsteps = POWER_UP_MICROSTEPS;
    vars.pulse_ns = POWER_UP_PULSE_NS;
    vars.setup_ns = POWER_UP_SETUP_NS;
    vars.encoder_kind = 0;
    vars.encoder_angle = 0;
    vars.holding_mnm = POWER_UP_HOLDING_MNM;
    vars.detent_mnm = POWER_UP_DETENT_MNM;
    vars.corner_rpm = POWER_UP_CORNER_RPM;
}

void device_power_up(void) {
    flashvars_load(&flash);
    splitter_reset(&splitter);
    out_length = 0;
    memset(debug_flags, 0, sizeof debug_flags);
    ram_defaults();
    vars.motor_pins = flash.motor;
    motor_pins_sample_t pins = {0};
    if (vars.motor_pins) {
        platform_motor_pins_start();
        platform_motor_pins_sample(&pins);
    }
    platform_outputs_start();
    platform_steps_start();
    steps_timing();
    derive();
    platform_servo_lock();
    servo_state_init(&servo_state, flash.default_control_mode);
    copy_in_locked();
    mq_clear();
    records.head = 0;
    records.tail = 0;
    records.dropped = 0;
    if (vars.motor_pins) {
        servo_pins_power_up(&servo_state, &servo_params, &pins);
    } else {
        servo_state.limits = servo_switches(&servo_state, &servo_params);
        servo_state.probe = servo_probe(&servo_state, &servo_params);
    }
    platform_servo_unlock();
}

void device_feed(const uint8_t *data, size_t length) {
    for (size_t i = 0; i < length; i++) {
        split_result_t split = splitter_byte(&splitter, data[i]);
        if (split == SPLIT_NONE) {
            continue;
        }
        /* the Python device interprets a line at a tick boundary, after the lines of the
         * ticks before it: print what core1 has recorded first */
        device_poll();
        if (split == SPLIT_LINE) {
            interpret(splitter.buffer, splitter.length);
            splitter_consumed(&splitter);
        } else {
            message_t m = {.length = 0};
            message_text(&m, "line longer than ");
            message_int(&m, TABLE_MAX_LINE_BYTES);
            message_text(&m, " bytes");
            print_err(NULL, m.text);
        }
    }
}

void device_poll(void) {
    uint32_t tail = records.tail;
    while (tail != records.head) {
        __atomic_thread_fence(__ATOMIC_ACQUIRE); /* the record is read after its head */
        record_t record = records.slots[tail % RECORD_RING_SLOTS];
        __atomic_thread_fence(__ATOMIC_RELEASE); /* ... and before its slot is given back */
        tail++;
        records.tail = tail;
        print_record(&record);
    }
}

void device_servo_tick(void) {
    platform_servo_lock();
    if (!simulated_motor()) {
        servo_tick_pins(&servo_state, &servo_params, &records);
    } else {
        servo_tick(&servo_state, &servo_params, &records);
    }
    platform_servo_unlock();
}

uint32_t device_tick_us(void) {
    return (uint32_t)vars.interval_dms * 100u;
}
