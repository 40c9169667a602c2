/* The absolute encoder's frames to counts (absenc.h). */
#include "absenc.h"

int32_t absenc_code(uint32_t high, uint32_t period) {
    if (high > period || period < 2u * ABSENC_FRAME) {
        return -1;
    }
    /* both below 2^19, so high x FRAME (< 2^19 x 4351 < 2^32) is one 32-bit product; a
     * period that long keeps over 120 units a clock period */
    while (period >= (1u << 19)) {
        period >>= 1;
        high >>= 1;
    }
    /* clocks = round(high x FRAME / period); the code is clocks - HEAD */
    uint32_t clocks = (high * ABSENC_FRAME + period / 2u) / period;
    int32_t code = (int32_t)clocks - (int32_t)ABSENC_HEAD;
    if (code == -1) {
        return 0;
    }
    if (code == (int32_t)ABSENC_CODES) {
        return (int32_t)ABSENC_CODES - 1;
    }
    if (code < 0 || code >= (int32_t)ABSENC_CODES) {
        return -1;
    }
    return code;
}

int32_t absenc_angle(int32_t code, int32_t turn) {
    return (int32_t)(((uint64_t)(uint32_t)code * (uint32_t)turn) >> 12);
}

int32_t absenc_move(int32_t from, int32_t to, int32_t turn) {
    int32_t move = to - from;
    if (move > turn / 2) {
        move -= turn;
    } else if (move <= -(turn - turn / 2)) {
        move += turn;
    }
    return move;
}
