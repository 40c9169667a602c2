/* TinyUSB configuration of the USB Motion Device: one full-speed CDC-ACM interface. */
#ifndef USBMOTION_TUSB_CONFIG_H
#define USBMOTION_TUSB_CONFIG_H

#ifndef CFG_TUSB_MCU
#error CFG_TUSB_MCU must be defined by the build (the Pico SDK defines OPT_MCU_RP2040)
#endif

#define CFG_TUSB_RHPORT0_MODE (OPT_MODE_DEVICE | OPT_MODE_FULL_SPEED)
#define CFG_TUD_ENABLED 1
#define CFG_TUSB_DEBUG 0

#define CFG_TUD_ENDPOINT0_SIZE 64

#define CFG_TUD_CDC 1
#define CFG_TUD_MSC 0
#define CFG_TUD_HID 0
#define CFG_TUD_MIDI 0
#define CFG_TUD_VENDOR 0

/* Bytes buffered in each direction. A received line is at most a few hundred bytes; the
 * transmit FIFO holds a burst of diagnostics lines while the host is slow to read. */
#define CFG_TUD_CDC_RX_BUFSIZE 1024
#define CFG_TUD_CDC_TX_BUFSIZE 2048
#define CFG_TUD_CDC_EP_BUFSIZE 64

#endif
