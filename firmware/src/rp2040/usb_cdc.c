/* core0: USB CDC through TinyUSB, the main loop and the device's output. */
#include <stddef.h>
#include <stdint.h>

#include "hardware/sync.h"
#include "tusb.h"

#include "device.h"
#include "platform.h"
#include "rp2040_platform.h"

/* Bytes taken from the CDC receive FIFO per device_feed call: one full-speed packet. */
#define FEED_CHUNK_BYTES 64

void platform_write(const char *bytes, size_t length) {
    while (length > 0) {
        if (!tud_cdc_connected()) {
            return; /* no host holds the port open: the bytes are dropped */
        }
        uint32_t queued = tud_cdc_write(bytes, (uint32_t)length);
        bytes += queued;
        length -= queued;
        if (length > 0) {
            /* The transmit FIFO is full: send what it holds and wait for the host to take it.
             * An event (the USB interrupt completing a transfer) ends the wait. */
            tud_cdc_write_flush();
            tud_task();
            if (tud_cdc_write_available() == 0 && !tud_task_event_ready()) {
                __wfe();
            }
        }
    }
}

static bool feed_received(void) {
    bool fed = false;
    uint8_t chunk[FEED_CHUNK_BYTES];
    while (tud_cdc_available() > 0) {
        uint32_t count = tud_cdc_read(chunk, sizeof chunk);
        if (count == 0) {
            break;
        }
        device_feed(chunk, count);
        fed = true;
    }
    return fed;
}

void usb_cdc_run(void) {
    tud_init(0);
    for (;;) {
        tud_task();
        feed_received();
        device_poll();
        tud_cdc_write_flush();
        /* Sleep until an event: any interrupt's entry or return, or core1's SEV after a tick.
         * WFE keeps an event that came after the checks, so none is lost (WFI would sleep
         * through a wake-up that arrived between the check and the instruction). */
        if (!tud_task_event_ready() && tud_cdc_available() == 0) {
            __wfe();
        }
    }
}
