/* USB descriptors of the USB Motion Device: a CDC-ACM serial port. */
#include <string.h>

#include "pico/unique_id.h"
#include "tusb.h"

#include "usb_ids.h"

enum {
    ITF_NUM_CDC = 0,
    ITF_NUM_CDC_DATA,
    ITF_NUM_TOTAL
};

#define EPNUM_CDC_NOTIF 0x81
#define EPNUM_CDC_OUT 0x02
#define EPNUM_CDC_IN 0x82
#define CONFIG_TOTAL_LEN (TUD_CONFIG_DESC_LEN + TUD_CDC_DESC_LEN)

enum {
    STRID_LANGID = 0,
    STRID_MANUFACTURER,
    STRID_PRODUCT,
    STRID_SERIAL,
    STRID_CDC,
    STRID_COUNT
};

static const tusb_desc_device_t device_descriptor = {
    .bLength = sizeof(tusb_desc_device_t),
    .bDescriptorType = TUSB_DESC_DEVICE,
    .bcdUSB = 0x0200,
    /* IAD: the CDC control and data interfaces form one function */
    .bDeviceClass = TUSB_CLASS_MISC,
    .bDeviceSubClass = MISC_SUBCLASS_COMMON,
    .bDeviceProtocol = MISC_PROTOCOL_IAD,
    .bMaxPacketSize0 = CFG_TUD_ENDPOINT0_SIZE,
    .idVendor = USBMOTION_USB_VID,
    .idProduct = USBMOTION_USB_PID,
    .bcdDevice = USBMOTION_USB_BCD_DEVICE,
    .iManufacturer = STRID_MANUFACTURER,
    .iProduct = STRID_PRODUCT,
    .iSerialNumber = STRID_SERIAL,
    .bNumConfigurations = 1,
};

static const uint8_t configuration_descriptor[] = {
    TUD_CONFIG_DESCRIPTOR(1, ITF_NUM_TOTAL, 0, CONFIG_TOTAL_LEN, 0, 100),
    TUD_CDC_DESCRIPTOR(ITF_NUM_CDC, STRID_CDC, EPNUM_CDC_NOTIF, 8, EPNUM_CDC_OUT, EPNUM_CDC_IN,
                       CFG_TUD_CDC_EP_BUFSIZE),
};

const uint8_t *tud_descriptor_device_cb(void) {
    return (const uint8_t *)&device_descriptor;
}

const uint8_t *tud_descriptor_configuration_cb(uint8_t index) {
    (void)index;
    return configuration_descriptor;
}

/* UTF-16 string descriptors, built on request into one static buffer (the USB stack copies it
 * out before asking for the next). */
static uint16_t string_descriptor[1 + 32];

const uint16_t *tud_descriptor_string_cb(uint8_t index, uint16_t langid) {
    (void)langid;
    char serial[2 * PICO_UNIQUE_BOARD_ID_SIZE_BYTES + 1];
    const char *text;
    size_t length;
    switch (index) {
    case STRID_LANGID:
        string_descriptor[1] = 0x0409; /* English (United States) */
        length = 1;
        string_descriptor[0] = (uint16_t)((TUSB_DESC_STRING << 8) | (2 * length + 2));
        return string_descriptor;
    case STRID_MANUFACTURER:
        text = USBMOTION_USB_MANUFACTURER;
        break;
    case STRID_PRODUCT:
        text = USBMOTION_USB_PRODUCT;
        break;
    case STRID_SERIAL:
        pico_get_unique_board_id_string(serial, sizeof serial);
        text = serial;
        break;
    case STRID_CDC:
        text = USBMOTION_USB_INTERFACE;
        break;
    default:
        return NULL;
    }
    length = strlen(text);
    if (length > 32) {
        length = 32;
    }
    for (size_t i = 0; i < length; i++) {
        string_descriptor[1 + i] = (uint8_t)text[i];
    }
    string_descriptor[0] = (uint16_t)((TUSB_DESC_STRING << 8) | (2 * length + 2));
    return string_descriptor;
}
