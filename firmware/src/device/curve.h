/* Curve mode (control mode 3): the keyframe buffer and its Hermite player, as
 * src/usbmotion/device/curve.py (CurvePlayer) and src/usbmotion/hermite.py
 * (hermite_position). The buffer functions are declared in servo.h. */
#ifndef USBMOTION_CURVE_H
#define USBMOTION_CURVE_H

#include <stdint.h>

#include "servo.h"

/* hermite.hermite_position: the cubic Hermite segment from p0 (out-tangent m0) to p1
 * (in-tangent m1, both 6:10 fixed point counts/ms) over duration_ms (1..65535), at
 * elapsed_us (0..duration_ms * 1000), evaluated exactly and rounded to the nearest count,
 * ties away from zero. The value may lie outside int32 (tangents overshooting near the
 * ends of the int32 range); it is within +-(2^31 + 2^20). */
int64_t curve_hermite_position(int32_t p0, int32_t p1, int32_t m0, int32_t m1,
                               uint32_t duration_ms, uint32_t elapsed_us);

/* CurvePlayer.next_position: the desired position of the next running tick (may exceed
 * int32: the caller wraps it as the counter does). */
int64_t curve_next_position(curve_player_t *curve, int32_t current_desired, int64_t tick_us);

#endif
