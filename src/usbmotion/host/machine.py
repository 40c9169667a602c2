"""A machine: several devices as named axes, configured from one file, started together.

:meth:`Machine.connect` opens one :class:`~usbmotion.host.device.DeviceClient` per axis of a
:class:`~usbmotion.host.config.MachineConfig`: axes named by their device name are found by
discovery, explicit ports and URLs are opened as they are. The host knows only ports:
``usbmotion.sim.machine.SimulatedMachine`` puts the simulated devices of ``sim://`` axes
behind such URLs. :meth:`Machine.configure` sends
the file's settings through the clients' validated methods; :meth:`Machine.synchronise`
zeroes the device clocks and arms a common start (call 31).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass

from usbmotion.clock import Clock
from usbmotion.errors import (
    ConfigError,
    DeviceError,
    DeviceNotFoundError,
    ErrReplyError,
    UsbMotionError,
)
from usbmotion.host.config import (
    SIM_MOTOR_CALLS,
    AxisConfig,
    MachineConfig,
    SimStepperConfig,
)
from usbmotion.host.device import AxisScale, ControlMode, DeviceClient, Status
from usbmotion.host.discovery import PROBE_TIMEOUT_S, discover
from usbmotion.host.spindle import Spindle
from usbmotion.host.timesync import (
    DEFAULT_MARGIN_S,
    DEFAULT_SAMPLES,
    SyncReport,
    shared_clock,
    synchronise_start,
)
from usbmotion.host.transport import LineTransport
from usbmotion.protocol import CallNumber, Drive
from usbmotion.protocol.table import max_steps_per_tick

SPINDLE_KEY = "spindle"
"""The spindle's device among the machine's links (discovery, URLs)."""


@dataclass(frozen=True, slots=True)
class Axis:
    """One axis of a connected machine.

    Fields:
        name: the axis letter.
        config: its configuration.
        client: the device that drives it.
        url: the port or URL it was opened on.
    """

    name: str
    config: AxisConfig
    client: DeviceClient
    url: str

    @property
    def scale(self) -> AxisScale:
        """Millimetres to counts."""
        return self.config.scale


class Machine:
    """Several devices as named axes.

    Build one with :meth:`connect`. A context manager; :meth:`close` is safe twice and
    closes every link (it does not move or disable anything: :meth:`stop` does).

    Parameters:
        config: the machine configuration.
        axes: the connected axes, in the configuration's order.

    Raises:
        ConfigError: the axes' links do not share one clock.
    """

    def __init__(self, config: MachineConfig, axes: Sequence[Axis],
                 spindle: Spindle | None = None) -> None:
        self.config = config
        self.axes: Mapping[str, Axis] = {axis.name: axis for axis in axes}
        self.spindle = spindle
        """The spindle device (``[spindle]``), or None."""
        self._closed = False
        try:
            self.clock: Clock = shared_clock([axis.client for axis in axes] + (
                [spindle.client] if spindle is not None else []))
        except UsbMotionError as error:
            raise ConfigError(
                f"{config.path}: {error}; a machine's axes must all be simulated in one"
                " world (sim://) or all be devices on ports", path=str(config.path),
            ) from error

    # --- connecting ------------------------------------------------------------------------

    @classmethod
    def connect(
        cls,
        config: MachineConfig,
        *,
        search_ports: bool = True,
        ports: Sequence[str] = (),
        probe_timeout_s: float = PROBE_TIMEOUT_S,
    ) -> Machine:
        """Open every axis's device.

        An axis given by ``device`` name only is found by discovery among ``ports``, the
        configuration's ``ports`` and (with ``search_ports``) the computer's serial ports.
        An axis given both a ``url`` and a ``device`` name is checked to answer to that name.

        A device may still be printing for a host that died or left (diagnostics it asked
        for, an echo, answers, the tail of a line): each link is taken over with
        :meth:`~usbmotion.host.device.DeviceClient.resynchronise`, which turns
        diagnostics off and skips every line up to the answer to its own query.

        Parameters:
            config: the machine configuration.
            search_ports: let discovery search the computer's serial ports.
            ports: more ports or URLs for discovery to search first.
            probe_timeout_s: how long each searched port has to answer its name.

        Raises:
            DeviceNotFoundError: a device name was not found, or a port answers to
                another name.
            LinkLostError: a port could not be opened.
            DeviceTimeoutError: a port did not answer the resynchronising query.
            ConfigError: the axes do not share one clock (simulated and real mixed).
        """
        urls = {axis.name: axis.url for axis in config.axes if axis.url is not None}
        spindle_config = config.spindle
        if spindle_config is not None and spindle_config.url is not None:
            urls[SPINDLE_KEY] = spindle_config.url
        opened: list[Axis] = []
        spindle: Spindle | None = None
        try:
            lost = [(axis.name, axis.device) for axis in config.axes if axis.name not in urls]
            if spindle_config is not None and SPINDLE_KEY not in urls:
                lost.append((SPINDLE_KEY, spindle_config.device))
            if lost:
                found = discover(
                    [device for _, device in lost if device is not None],
                    urls=list(ports) + list(config.ports), search_ports=search_ports,
                    timeout_s=probe_timeout_s,
                )
                for key, device in lost:
                    assert device is not None
                    urls[key] = found[device]
            for axis in config.axes:
                url = urls[axis.name]
                client = DeviceClient(
                    LineTransport.open(url, label=axis.label), name=axis.label,
                    timeout_s=config.reply_timeout_s,
                )
                client.scale = axis.scale
                opened.append(Axis(axis.name, axis, client, url))
            if spindle_config is not None:
                client = DeviceClient(
                    LineTransport.open(urls[SPINDLE_KEY], label=spindle_config.label),
                    name=spindle_config.label, timeout_s=config.reply_timeout_s)
                spindle = Spindle(client, spindle_config,
                                  servo_interval_dms=config.servo_interval_dms,
                                  watchdog_ms=config.watchdog_ms)
            machine = cls(config, opened, spindle)
        except BaseException:
            for axis_open in opened:
                axis_open.client.close()
            if spindle is not None:
                spindle.client.close()
            raise
        try:
            for axis_open in opened:
                _take_over(axis_open.client, f"axis {axis_open.name}",
                           axis_open.config.device, axis_open.config.url)
            if spindle is not None:
                _take_over(spindle.client, "spindle", spindle.config.device,
                           spindle.config.url)
        except BaseException:
            machine.close()
            raise
        return machine

    # --- configuring -----------------------------------------------------------------------

    def configure(self) -> None:
        """Send the configuration to every device, servos disabled first.

        What the device drives (call 44) and, on a stepper axis, its motor and driver
        (calls 45, 46; call 16 for a closed loop's encoder); servo interval and motion
        scalar, control mode 1 (position) with its PID gains, following-error limit,
        watchdog; for axes with a simulated motor its values and travel (a simulated
        stepper's torques, call 47). Each goes through the client's validated, confirmed
        setter. A device whose drive or microsteps change starts counting afresh at 0, so
        its homed mark is cleared (it must home again).

        Raises:
            OutOfRangeError: a value the device cannot take (names the axis's device).
            ErrReplyError, DeviceTimeoutError, LinkLostError: a device refused or is gone.
        """
        config = self.config
        for axis in self.axes.values():
            client, settings = axis.client, axis.config
            client.set_servo_enable(False)
            _set_drive(client, settings, servo_interval_dms=config.servo_interval_dms)
            client.set_motion_scalar(config.motion_scalar)
            _set_mode(client, settings, ControlMode.POSITION)
            client.set_following_error_limit(settings.following_error_limit_counts)
            client.set_watchdog_ms(config.watchdog_ms)
            sim = settings.sim
            travel = settings.sim_travel_counts
            if sim is not None and travel is not None:
                client.set_sim_interval_dms(sim.update_interval_dms)
                for key, call in SIM_MOTOR_CALLS:
                    if hasattr(sim, key):  # a stepper has no voltage, torque constant, winding
                        client.set_sim_value(call, getattr(sim, key), label=key)
                if isinstance(sim, SimStepperConfig):
                    client.set_sim_stepper(sim.holding_torque_mnm, sim.detent_torque_mnm,
                                           sim.corner_rpm)
                else:
                    client.set_sim_counts_per_revolution(sim.counts_per_revolution)
                client.set_sim_travel(*travel)
                client.set_sim_probe(*settings.sim_probe_counts)
            _set_encoder(client, settings)
        if self.spindle is not None:
            self.spindle.configure()

    def reconfigure(self, config: MachineConfig) -> None:
        """Take a changed configuration of the same machine: its host-side values (scale,
        limits, travel, homing, planning) take effect at once; of what :meth:`configure`
        sends, the following-error limit (it is in counts: it follows the scale), the
        position gains and a stepper driver's timing are sent again when they changed (the
        devices hold in position mode while the machine is idle; the velocity gains take
        effect at the next homing). Each axis keeps the link it was connected on.

        Raises:
            ConfigError: the axes, their devices or a value only a restart applies differ
                (the message names it).
            OutOfRangeError, ErrReplyError, DeviceTimeoutError, LinkLostError: sending the
                following-error limit failed.
        """
        old = self.config
        if config.axis_names != old.axis_names:
            raise ConfigError(f"{config.path}: the axes {', '.join(config.axis_names)} are not"
                              f" those connected ({', '.join(old.axis_names)}): restart",
                              path=str(config.path))
        fixed = ("servo_interval_dms", "motion_scalar", "watchdog_ms")
        for key in fixed:
            if getattr(config, key) != getattr(old, key):
                raise ConfigError(f"{config.path}: {key} takes effect only when the machine"
                                  " connects: restart", path=str(config.path), key=key)
        spindle = config.spindle
        if old.spindle is not None and spindle is not None:
            spindle = dataclasses.replace(spindle, url=old.spindle.url)
        if spindle != old.spindle:
            raise ConfigError(f"{config.path}: spindle takes effect only when the machine"
                              " connects: restart", path=str(config.path), key="spindle")
        config = dataclasses.replace(config, spindle=spindle, axes=tuple(
            dataclasses.replace(axis, url=self.axes[axis.name].config.url)
            for axis in config.axes))
        for axis in self.axes.values():
            new = config.axis(axis.name)
            for key in ("device", "sim", "stepper", "absolute_encoder"):
                old_value, new_value = getattr(axis.config, key), getattr(new, key)
                if key == "stepper" and old_value is not None and new_value is not None:
                    # the driver's timing (grbl's $0) is sent at once, the rest on connecting
                    old_value = dataclasses.replace(old_value, step_pulse_ns=0, dir_setup_ns=0)
                    new_value = dataclasses.replace(new_value, step_pulse_ns=0, dir_setup_ns=0)
                if new_value != old_value:
                    label = "encoder" if key == "absolute_encoder" else key
                    raise ConfigError(
                        f"{config.path}: axes.{axis.name}.{label} takes effect only when the"
                        " machine connects: restart", path=str(config.path),
                        key=f"axes.{axis.name}.{label}")
        axes = {}
        for axis in self.axes.values():
            new = config.axis(axis.name)
            if new.following_error_limit_counts != axis.config.following_error_limit_counts:
                axis.client.set_following_error_limit(new.following_error_limit_counts)
            if new.gains != axis.config.gains:  # idle: the devices hold in position mode
                axis.client.set_gains(kp=new.gains.kp, ki=new.gains.ki, kd=new.gains.kd)
            if new.stepper is not None and new.stepper != axis.config.stepper:
                axis.client.set_step_timing(new.stepper.step_pulse_ns, new.stepper.dir_setup_ns)
            axis.client.scale = new.scale
            axes[axis.name] = Axis(axis.name, new, axis.client, axis.url)
        self.axes = axes
        self.config = config

    # --- the axes together -----------------------------------------------------------------

    @property
    def clients(self) -> list[DeviceClient]:
        """The axes' device clients, in axis order."""
        return [axis.client for axis in self.axes.values()]

    def axis(self, name: str) -> Axis:
        """The axis with this letter.

        Raises:
            KeyError: no such axis (the message lists the axes there are).
        """
        try:
            return self.axes[name]
        except KeyError:
            raise KeyError(
                f"no axis {name!r}; this machine has {', '.join(self.axes)}"
            ) from None

    def set_mode(self, mode: ControlMode, *, axes: Iterable[str] | None = None) -> None:
        """Switch axes (all by default) to a control mode, with that mode's gains.

        Velocity mode gets the configuration's ``velocity_gains``, position and curve modes
        its ``gains``; the gains go first, so the loop never runs a tick of the new mode
        on the old mode's gains. Changing the mode clears the motion queue.

        Raises:
            KeyError: an unknown axis name.
            DeviceError: a device refused (names it), after trying every axis.
        """
        chosen = [self.axis(name) for name in (axes if axes is not None else self.axes)]
        failures: list[str] = []
        for axis in chosen:
            try:
                _set_mode(axis.client, axis.config, mode)
            except (UsbMotionError, OSError) as error:
                failures.append(f"{axis.name}: {error}")
        if failures:
            raise DeviceError(f"could not set control mode {int(mode)}: " + "; ".join(failures),
                              device=", ".join(f.split(":", 1)[0] for f in failures),
                              call=CallNumber.SET_CONTROL_MODE)

    def status(self) -> dict[str, Status]:
        """Each axis's status (call 20), by axis letter."""
        return {name: axis.client.status() for name, axis in self.axes.items()}

    def positions_mm(self) -> dict[str, float]:
        """Each axis's actual position, mm."""
        return {
            name: axis.scale.to_mm(status.actual_counts)
            for (name, axis), status in zip(self.axes.items(), self.status().values(),
                                            strict=True)
        }

    def enable(self, on: bool) -> None:
        """Enable (or disable) every servo.

        Enabling stops at the first axis that refuses (a latched fault, say) and then
        disables every axis before raising, so the machine never runs half enabled.

        Raises:
            DeviceError: an axis refused or failed (names it); with ``on=False`` after
                every axis was tried.
        """
        if not on:
            self._each("disable", lambda axis: axis.client.set_servo_enable(False))
            return
        for axis in self.axes.values():
            try:
                axis.client.set_servo_enable(True)
            except (UsbMotionError, OSError) as error:
                try:
                    self._each("disable", lambda each: each.client.set_servo_enable(False))
                except DeviceError as also:
                    raise DeviceError(f"{error}; then {also}", device=axis.name,
                                      call=CallNumber.SET_SERVO_ENABLE) from error
                raise DeviceError(
                    f"axis {axis.name} could not be enabled ({error}); every axis was disabled",
                    device=axis.name, call=CallNumber.SET_SERVO_ENABLE,
                ) from error

    def ping(self) -> dict[str, tuple[int, int]]:
        """Ask every device its queue state (call 2); any command resets its watchdog.

        A loop that leaves enabled axes alone for longer than ``watchdog_ms`` (homing one
        axis while the others wait, say) calls this to keep them enabled; the spindle's
        device is asked too.

        Returns:
            axis letter -> (values queued, free slots).
        """
        if self.spindle is not None:
            self.spindle.client.queue_status()
        return {name: axis.client.queue_status() for name, axis in self.axes.items()}

    def clear_queues(self) -> None:
        """Empty every motion queue (each axis holds its last desired position).

        Raises:
            DeviceError: after trying every axis, naming each that failed.
        """
        self._each("clear the queue of", lambda axis: axis.client.clear_queue())

    def clear_faults(self) -> None:
        """Clear every latched fault (call 30).

        Raises:
            DeviceError: after trying every axis, naming each that failed.
        """
        self._each("clear the fault of", lambda axis: axis.client.clear_fault())

    def stop(self) -> None:
        """The safe stop: clear every queue and disable every servo.

        Every step is tried on every axis even when some fail; the failures are then
        raised together.

        Raises:
            DeviceError: naming each axis and step that failed.
        """
        failures: list[str] = []
        for name, axis in self.axes.items():
            for step, action in (("clear queue", axis.client.clear_queue),
                                 ("disable", lambda a=axis: a.client.set_servo_enable(False))):
                try:
                    action()
                except (UsbMotionError, OSError) as error:
                    failures.append(f"{name} ({step}): {error}")
        if self.spindle is not None:
            try:
                self.spindle.halt()
            except (UsbMotionError, OSError) as error:
                failures.append(f"spindle (stop): {error}")
        if failures:
            raise DeviceError(
                f"stop failed on {len(failures)} step(s): " + "; ".join(failures),
                device=", ".join(sorted({f.split(" ", 1)[0] for f in failures})),
            )

    def _each(self, what: str, action: Callable[[Axis], None]) -> None:
        failures: list[tuple[str, Exception]] = []
        for name, axis in self.axes.items():
            try:
                action(axis)
            except (UsbMotionError, OSError) as error:
                failures.append((name, error))
        if failures:
            detail = "; ".join(f"{name}: {error}" for name, error in failures)
            raise DeviceError(
                f"could not {what} {len(failures)} axis/axes: {detail}",
                device=", ".join(name for name, _ in failures),
            ) from failures[0][1]

    # --- time --------------------------------------------------------------------------------

    def synchronise(
        self,
        *,
        samples: int = DEFAULT_SAMPLES,
        margin_s: float = DEFAULT_MARGIN_S,
        axes: Iterable[str] | None = None,
    ) -> SyncReport:
        """Zero the device clocks, measure them and arm a common start (call 31).

        The servos must be enabled for the queues to start. See
        :func:`usbmotion.host.timesync.synchronise_start`.
        """
        names = list(axes) if axes is not None else list(self.axes)
        return synchronise_start([self.axis(n).client for n in names], samples=samples,
                                 margin_s=margin_s)

    # --- lifetime ----------------------------------------------------------------------------

    def close(self) -> None:
        """Close every link (safe twice)."""
        if self._closed:
            return
        self._closed = True
        for axis in self.axes.values():
            axis.client.close()
        if self.spindle is not None:
            self.spindle.client.close()

    def __enter__(self) -> Machine:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _take_over(client: DeviceClient, label: str, device: str | None,
               url: str | None) -> None:
    """Diagnostics off and the link resynchronised; then the name checked, if one is set
    (``label``: ``axis X``, ``spindle``).

    Raises:
        DeviceNotFoundError: the port answers to another name than the configured one.
    """
    client.resynchronise(stop_diagnostics=True)
    if device is not None and url is not None:
        answered = client.device_name()
        if answered != device:
            raise DeviceNotFoundError(
                f"{label}: {url} answers to {answered!r}, not to the configured device"
                f" {device!r}", name=device, searched=(url,))


def _set_drive(client: DeviceClient, axis: AxisConfig, *, servo_interval_dms: int) -> None:
    """The servo interval and what the device drives (servo disabled): a stepper's drive,
    motor and timing, or the DC motor. The drive is set only when it differs (a change
    starts the counter afresh: the homed mark is cleared then, and when the microsteps
    change). A device that does not know call 44 (firmware before steppers) drives a DC
    motor."""
    stepper = axis.stepper
    if stepper is None:
        try:
            drive = client.drive()
        except ErrReplyError:
            drive = Drive.DC
        if drive is not Drive.DC:
            client.set_drive(Drive.DC)
            client.set_homed_marker(0)
        client.set_servo_interval_dms(servo_interval_dms)
        return
    timing = (stepper.step_pulse_ns, stepper.dir_setup_ns)
    # Call 46 and call 5 are each refused when no step fits the tick: send the timing first
    # when it fits the present tick (the file's pair fits its own tick).
    timing_first = max_steps_per_tick(client.servo_interval_us(), *timing) >= 1
    if timing_first:
        client.set_step_timing(*timing)
    client.set_servo_interval_dms(servo_interval_dms)
    if not timing_first:
        client.set_step_timing(*timing)
    steps = (stepper.full_steps_per_rev, stepper.microsteps)
    if client.stepper() != steps:
        client.set_stepper(*steps)
        client.set_homed_marker(0)
    if stepper.encoder_counts_per_rev is not None:
        client.set_sim_counts_per_revolution(stepper.encoder_counts_per_rev)
    if client.drive() is not stepper.drive:
        client.set_drive(stepper.drive)
        client.set_homed_marker(0)


def _set_encoder(client: DeviceClient, axis: AxisConfig) -> None:
    """The axis's encoder (call 49, servo disabled), sent only when it differs from the
    device's: an absolute one makes the counter the angle within a turn, so the device's
    homed mark is cleared then. A real servo's absolute encoder gets its turn (call 16)
    first (a simulated motor's, the same by the file's check, went with its values). A
    device that does not know call 49 reads an incremental encoder."""
    absolute = axis.absolute_encoder
    try:
        now = client.encoder()
    except ErrReplyError:
        if absolute is None:
            return
        raise
    if absolute is None:
        if now.absolute:
            client.set_encoder(0, 0)
        return
    if axis.stepper is None and axis.sim is None:  # a simulated motor's was sent with it
        client.set_sim_counts_per_revolution(absolute.turn_counts)
    if (now.kind, now.angle) != (1, absolute.magnet_counts):
        client.set_encoder(1, absolute.magnet_counts)
        client.set_homed_marker(0)


def _set_mode(client: DeviceClient, axis: AxisConfig, mode: ControlMode) -> None:
    gains = axis.velocity_gains if mode is ControlMode.VELOCITY else axis.gains
    client.set_gains(kp=gains.kp, ki=gains.ki, kd=gains.kd)
    client.set_control_mode(mode)
