/* The USB Motion Device on the RP2040: core0 runs USB CDC and the interpreter, core1 the servo
 * tick from a hardware alarm. */
#include "device.h"
#include "rp2040_platform.h"

int main(void) {
    servo_lock_init();
    motion_queue_init();
    device_power_up();
    servo_start();
    usb_cdc_run();
}
