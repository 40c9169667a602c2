/* The absolute encoder on the pins (call 49 kind 1): an AS5161-style magnetic angle sensor's
 * PWM output, a frame at a time, to the angle within a turn in counts of the counter, counted
 * on across turns. Not in the Python device (it has no pins); portable, so the native build
 * tests it. */
#ifndef USBMOTION_ABSENC_H
#define USBMOTION_ABSENC_H

#include <stdbool.h>
#include <stdint.h>

/* The frame, in the sensor's PWM clock periods: ams's 12-bit PWM angle frame, a start of
 * ABSENC_HEAD high, then the angle's code (0..4095) high and the rest of the 4095-period data
 * part low, then an end of ABSENC_TAIL low; the duty is (HEAD + code) / FRAME. */
#define ABSENC_HEAD 128u
#define ABSENC_CODES 4096u
#define ABSENC_TAIL 128u
#define ABSENC_FRAME (ABSENC_HEAD + ABSENC_CODES - 1u + ABSENC_TAIL)   /* 4351 */

/* The time with no frame (or none a sensor sends) after which the encoder is lost, us: about
 * four frames of the 920 Hz PWM (a frame is 1.09 ms; 1.2 ms with the sensor's clock 10 %
 * slow). A servo enabled on a lost encoder latches fault 5 (FAULT_ENCODER_LOST). */
#define ABSENC_TIMEOUT_US 5000

/* The code (0..4095) of a frame high for `high` of `period` (any unit, the same for both),
 * high / period taken to the nearest of the frame's clock periods; -1 for a frame no sensor
 * sends (its duty more than half a clock period outside the codes' range, or a period of
 * fewer than two units per clock period). */
int32_t absenc_code(uint32_t high, uint32_t period);

/* The angle of a code in counts of a turn of `turn` counts: floor(code x turn / 4096). */
int32_t absenc_angle(int32_t code, int32_t turn);

/* The counter's source, counted on across turns: an angle that moved by more than half a turn
 * since the last frame wrapped (overflow: a turn up; underflow: a turn down). */
typedef struct {
    bool have;        /* a frame was taken since the reader started */
    uint32_t frames;  /* the platform's frame count when it was */
    int32_t angle;    /* its angle within the turn, counts */
    int64_t source;   /* the angle counted on across turns */
    int64_t base;     /* the source's count where the angle is 0 (set by the first frame):
                       * the angle of a source s is (s - base) floored modulo the turn */
} absenc_t;

/* The angle's move from `from` to `to` within a turn of `turn` counts, taken the short way
 * round: -turn/2 < move <= turn/2. */
int32_t absenc_move(int32_t from, int32_t to, int32_t turn);

#endif
