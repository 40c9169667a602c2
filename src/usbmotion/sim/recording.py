"""What simulated devices actually executed: every device's desired position at every
servo tick, recorded inside the world as the ticks run (the device-side truth, whatever
the host believed it sent), with an optional hook called on every tick of one device.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import numpy.typing as npt

from usbmotion.device import Device
from usbmotion.sim.world import SimWorld


class ExecutedRecorder:
    """Records, for the named devices of a world, the device clock and the desired position
    after every servo tick (a context manager: leaving it stops recording). While it
    records, the world runs its devices in step with its clock (never ahead).

    Parameters:
        world: the world the devices run in.
        keys: the devices (world keys: the machine's axis names).
        on_tick: called with the clock of the first device after each of its ticks.
    """

    def __init__(self, world: SimWorld, keys: list[str], *,
                 on_tick: Callable[[int], None] | None = None) -> None:
        self.clocks: dict[str, list[int]] = {key: [] for key in keys}
        self.desired: dict[str, list[int]] = {key: [] for key in keys}
        self._devices: dict[str, Device] = {}
        self._world = world
        self._ran_ahead = world.run_ahead
        world.run_ahead = False  # every tick recorded once, at the world's time
        for index, key in enumerate(keys):
            device = world.device(key)
            if not isinstance(device, Device):
                raise TypeError(f"{key}: {device!r} is not a Python device")
            self._devices[key] = device
            device.__dict__["run"] = self._stepper(key, device, on_tick if index == 0 else None)

    def _stepper(self, key: str, device: Device,
                 on_tick: Callable[[int], None] | None) -> Callable[[int], None]:
        run = type(device).run
        clocks, desired = self.clocks[key], self.desired[key]

        def step(ticks: int) -> None:
            for _ in range(ticks):
                run(device, 1)
                clock = device.clock
                clocks.append(clock)
                desired.append(device.desired)
                if on_tick is not None:
                    on_tick(clock)
        return step

    def positions(self) -> npt.NDArray[np.int64]:
        """Every device's desired position at every tick since recording began (the devices
        of one world tick together), one row per tick, one column per device in the order
        of ``keys``."""
        length = min(len(values) for values in self.desired.values())
        return np.array([values[:length] for values in self.desired.values()],
                        dtype=np.int64).T

    def close(self) -> None:
        """Stop recording (safe twice)."""
        for device in self._devices.values():
            device.__dict__.pop("run", None)
        if self._devices:
            self._world.run_ahead = self._ran_ahead
        self._devices = {}

    def __enter__(self) -> ExecutedRecorder:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
