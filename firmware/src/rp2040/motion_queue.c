/* The motion queue: an SDK queue_t of int32_t between core0 (adds) and core1 (removes). */
#include <stdbool.h>
#include <stdint.h>
#include <string.h>

#include "hardware/sync.h"
#include "pico/util/queue.h"

#include "platform.h"
#include "rp2040_platform.h"

static queue_t motion_queue;

void motion_queue_init(void) {
    queue_init(&motion_queue, sizeof(int32_t), MOTION_QUEUE_CAPACITY);
}

bool __not_in_flash_func(mq_try_add)(int32_t value) {
    return queue_try_add(&motion_queue, &value);
}

bool __not_in_flash_func(mq_try_remove)(int32_t *value) {
    return queue_try_remove(&motion_queue, value);
}

uint32_t __not_in_flash_func(mq_level)(void) {
    return queue_get_level(&motion_queue);
}

/* queue_t has no clear or peek: both work on its fields under the queue's own spinlock, as
 * queue_try_add and queue_try_remove do. */
void mq_clear(void) {
    uint32_t save = spin_lock_blocking(motion_queue.core.spin_lock);
    motion_queue.rptr = motion_queue.wptr;
    spin_unlock(motion_queue.core.spin_lock, save);
}

/* Keeps the first count values from the head (the ones core1 takes next), drops the rest:
 * the write index moves back, so it costs the same whatever the number dropped. */
void mq_truncate(uint32_t count) {
    uint32_t save = spin_lock_blocking(motion_queue.core.spin_lock);
    if (count < queue_get_level_unsafe(&motion_queue)) {
        uint32_t slot = motion_queue.rptr + count;
        if (slot > motion_queue.element_count) {
            slot -= (uint32_t)motion_queue.element_count + 1;
        }
        motion_queue.wptr = (uint16_t)slot;
    }
    spin_unlock(motion_queue.core.spin_lock, save);
}

int32_t mq_peek(uint32_t index) {
    int32_t value = 0;
    uint32_t save = spin_lock_blocking(motion_queue.core.spin_lock);
    if (index < queue_get_level_unsafe(&motion_queue)) {
        /* element_count + 1 slots, as the SDK's ring keeps one free */
        uint32_t slot = motion_queue.rptr + index;
        if (slot > motion_queue.element_count) {
            slot -= (uint32_t)motion_queue.element_count + 1;
        }
        memcpy(&value, motion_queue.data + slot * sizeof(int32_t), sizeof value);
    }
    spin_unlock(motion_queue.core.spin_lock, save);
    return value;
}
