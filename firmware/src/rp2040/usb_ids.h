/* How the USB Motion Device names itself on the bus. */
#ifndef USBMOTION_USB_IDS_H
#define USBMOTION_USB_IDS_H

/* Raspberry Pi's vendor ID. The product ID is this project's choice within it; a product that
 * ships needs one allocated by Raspberry Pi (their PID programme) or its own vendor ID. */
#define USBMOTION_USB_VID 0x2E8A
#define USBMOTION_USB_PID 0x10E1
#define USBMOTION_USB_BCD_DEVICE 0x0100

#define USBMOTION_USB_MANUFACTURER "usbmotion"
#define USBMOTION_USB_PRODUCT "USB Motion Device"
#define USBMOTION_USB_INTERFACE "USB Motion Device CDC"

#endif
