"""Small helpers shared by the device tests."""

from __future__ import annotations

from collections.abc import Iterator

from usbmotion.device import Device, DeviceState


def send(device: Device, *lines: str) -> list[str]:
    """Feed ``lines`` (each gets a newline) and return what the device printed, as lines."""
    device.feed("".join(line + "\n" for line in lines).encode("ascii"))
    return take(device)


def take(device: Device) -> list[str]:
    """What the device printed since the last take, as lines without newlines."""
    text = device.take_output().decode("ascii")
    assert text == "" or text.endswith("\n"), text
    return text.splitlines()


def states(device: Device, ticks: int) -> Iterator[DeviceState]:
    """Run ``ticks`` ticks one at a time, yielding the device's state after each."""
    for _ in range(ticks):
        device.run(1)
        yield device.state


def positions(device: Device, ticks: int) -> list[int]:
    """Run ``ticks`` ticks one at a time and return the encoder count after each."""
    return [state.actual for state in states(device, ticks)]


def desired_positions(device: Device, ticks: int) -> list[int]:
    """Run ``ticks`` ticks one at a time and return the desired position after each (read
    from the snapshot, and checked against :attr:`Device.desired`, what a recorder reads)."""
    desired = []
    for state in states(device, ticks):
        assert device.desired == state.desired
        desired.append(state.desired)
    return desired
