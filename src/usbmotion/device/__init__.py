"""The device firmware: core0 (commands), core1 (servo loop), motor, curve mode, flash.

:class:`Device` is a USB Motion Device in virtual time: feed it bytes, run it by servo
ticks, take what it printed.
"""

from usbmotion.device.core0 import Device, DeviceSettings, DeviceState, Gains
from usbmotion.device.flash import FileFlash, Flash, FlashContents, MemoryFlash
from usbmotion.device.motor import MotorConstants, MotorParams

__all__ = [
    "Device",
    "DeviceSettings",
    "DeviceState",
    "FileFlash",
    "Flash",
    "FlashContents",
    "Gains",
    "MemoryFlash",
    "MotorConstants",
    "MotorParams",
]
