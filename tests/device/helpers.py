"""Small helpers shared by the device tests."""

from __future__ import annotations

from usbmotion.device import Device


def send(device: Device, *lines: str) -> list[str]:
    """Feed ``lines`` (each gets a newline) and return what the device printed, as lines."""
    device.feed("".join(line + "\n" for line in lines).encode("ascii"))
    return take(device)


def take(device: Device) -> list[str]:
    """What the device printed since the last take, as lines without newlines."""
    text = device.take_output().decode("ascii")
    assert text == "" or text.endswith("\n"), text
    return text.splitlines()


def positions(device: Device, ticks: int) -> list[int]:
    """Run ``ticks`` ticks one at a time and return the encoder count after each."""
    out = []
    for _ in range(ticks):
        device.run(1)
        out.append(device.state.actual)
    return out
