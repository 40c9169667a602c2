"""Sustained streaming of setpoints from the host into devices on pseudo-terminals.

    python benchmarks/streaming.py [--devices 1 3 6] [--seconds 3] [--runs 3] [--json]

``usbmotion sim --pty N`` serves N simulated devices in real time (a separate process,
ticking by the wall clock, reaped however a run ends); the host opens each pseudo-terminal
with pyserial, sets the devices to a 10 kHz servo period with one setpoint per tick (the
fastest the protocol allows: each device takes 10,000 setpoints/s) and streams
``--seconds`` of setpoints into every device at once with ``SetpointStream`` and
``run_streams`` (flow control by predicted consumption and call-2 checks), then waits until
the queues are drained.

Figures, each the median of ``--runs`` runs:

- sustained setpoints/s, all devices together: setpoints confirmed queued over the wall
  time from the first batch until the last queue ran dry;
- the ceiling the devices impose: N x 10,000 setpoints/s (a device cannot take more in
  real time), and how close the stream came to it;
- host CPU time per 1,000 setpoints (validation, encoding, writing, replies), and the
  host's capacity it implies (1,000 / that time): what the host could sustain if devices
  took more; the server process's CPU per 1,000 setpoints beside it;
- the lowest queue level seen after the first batch (0 means a device ran dry: the host
  fell behind).

The target, 50,000 setpoints/s in total, needs at least 5 devices at 10 kHz (the device
ceiling) and a host whose capacity exceeds it.
"""

from __future__ import annotations

import contextlib
import os
import platform
import statistics
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from _common import argument_parser, emit, parse_arguments, table_row
from _processes import sim_server
from usbmotion.host.device import DeviceClient
from usbmotion.host.stream import SetpointStream, run_streams, wait_until_drained
from usbmotion.host.transport import LineTransport

TARGET_SETPOINTS_S = 50_000
SERVO_INTERVAL_DMS = 1
DEVICE_CEILING_S = 10_000
"""Setpoints one device takes per second at a 10 kHz servo rate, scalar 1."""
_CLOCK_TICKS_S = os.sysconf("SC_CLK_TCK")


def _process_cpu_s(pid: int) -> float:
    """User + system CPU seconds of a running process (Linux ``/proc``)."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / _CLOCK_TICKS_S


@dataclass(frozen=True, slots=True)
class Run:
    """One run's raw figures."""

    setpoints: int
    wall_s: float
    host_cpu_s: float
    server_cpu_s: float
    min_queued: int
    refusals: int


def one_run(devices: int, seconds: float) -> Run:
    """Serve ``devices`` devices on ptys and stream ``seconds`` of setpoints into each."""
    with (tempfile.TemporaryDirectory(prefix="usbmotion-bench-") as flash_dir,
          sim_server(devices, Path(flash_dir)) as (server_pid, paths),
          contextlib.ExitStack() as opened):
        clients = [opened.enter_context(DeviceClient(LineTransport.open(path),
                                                     name=f"device {index}", timeout_s=2.0))
                   for index, path in enumerate(paths)]
        for client in clients:
            client.set_servo_interval_dms(SERVO_INTERVAL_DMS)
            client.set_motion_scalar(1)
            client.set_servo_enable(True)
        period_s = clients[0].motion_period_s()
        count = round(seconds / period_s)
        ramp = np.arange(count, dtype=np.int64) // 8
        streams = [SetpointStream(client, ramp * (index + 1), period_s=period_s)
                   for index, client in enumerate(clients)]
        host_before = time.process_time()
        server_before = _process_cpu_s(server_pid)
        started = time.perf_counter()
        run_streams(streams)
        wait_until_drained(clients, period_s=period_s, poll_s=0.002)
        wall_s = time.perf_counter() - started
        host_cpu_s = time.process_time() - host_before
        server_cpu_s = _process_cpu_s(server_pid) - server_before
        results = [stream.result() for stream in streams]
        for client in clients:
            client.set_servo_enable(False)
    return Run(
        setpoints=sum(result.sent for result in results),
        wall_s=wall_s,
        host_cpu_s=host_cpu_s,
        server_cpu_s=server_cpu_s,
        min_queued=min(result.min_queued for result in results),
        refusals=sum(result.refusals for result in results),
    )


def measure(*, device_counts: list[int], seconds: float, runs: int) -> dict[str, Any]:
    """Every figure, for each number of devices."""
    rows = []
    for devices in device_counts:
        samples = [one_run(devices, seconds) for _ in range(runs)]
        rate = statistics.median(s.setpoints / s.wall_s for s in samples)
        host_per_1000 = statistics.median(s.host_cpu_s / s.setpoints * 1000 for s in samples)
        server_per_1000 = statistics.median(s.server_cpu_s / s.setpoints * 1000 for s in samples)
        ceiling = devices * DEVICE_CEILING_S
        rows.append({
            "devices": devices,
            "setpoints_per_run": samples[0].setpoints,
            "setpoints_s": rate,
            "device_ceiling_setpoints_s": ceiling,
            "share_of_ceiling": rate / ceiling,
            "host_cpu_ms_per_1000": host_per_1000 * 1000,
            "host_capacity_setpoints_s": 1.0 / host_per_1000 * 1000,
            "server_cpu_ms_per_1000": server_per_1000 * 1000,
            "min_queued": min(s.min_queued for s in samples),
            "refusals": sum(s.refusals for s in samples),
            "meets_target": rate >= TARGET_SETPOINTS_S,
        })
    return {
        "benchmark": "streaming",
        "python": platform.python_version(),
        "cpus": os.cpu_count(),
        "runs": runs,
        "seconds_per_device": seconds,
        "servo_rate_hz": 1_000_000 // (SERVO_INTERVAL_DMS * 100),
        "target_setpoints_s": TARGET_SETPOINTS_S,
        "rows": rows,
    }


def limit_of(row: dict[str, Any]) -> str:
    """What bounds one row's rate, in words."""
    if row["share_of_ceiling"] >= 0.95:
        bound = (f"the devices: {row['devices']} x {DEVICE_CEILING_S:,} setpoints/s in real"
                 " time")
    elif row["min_queued"] == 0:
        bound = "the host or the server fell behind (a queue ran dry)"
    else:
        bound = "start-up and drain time around the stream"
    return (f"bound by {bound}; the host would sustain"
            f" {row['host_capacity_setpoints_s']:,.0f}/s on its own")


_COLUMNS = (">7", ">12", ">9", ">6", ">13", ">15", ">10")


def report(figures: dict[str, Any]) -> str:
    """The figures as text."""
    lines = [
        f"streaming: setpoints into `usbmotion sim --pty N` devices at"
        f" {figures['servo_rate_hz']:,} Hz, {figures['seconds_per_device']:g} s per device,"
        f" median of {figures['runs']} runs, Python {figures['python']},"
        f" {figures['cpus']} CPUs",
        table_row(
            ("devices", "setpoints/s", "ceiling", "share", "host ms/1000", "server ms/1000",
             "min queue"),
            _COLUMNS, gap=" ",
        ),
    ]
    for row in figures["rows"]:
        lines.append(table_row(
            (str(row["devices"]), f"{row['setpoints_s']:,.0f}",
             f"{row['device_ceiling_setpoints_s']:,}", f"{row['share_of_ceiling']:.0%}",
             f"{row['host_cpu_ms_per_1000']:.2f}", f"{row['server_cpu_ms_per_1000']:.2f}",
             str(row["min_queued"])),
            _COLUMNS, gap=" ",
        ))
        lines.append(f"        {limit_of(row)}")
    best = max(figures["rows"], key=lambda row: row["setpoints_s"])
    lines.append(
        f"target {figures['target_setpoints_s']:,} setpoints/s in total:"
        f" {'met' if best['meets_target'] else 'not met'} (best"
        f" {best['setpoints_s']:,.0f}/s with {best['devices']} devices)"
    )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> dict[str, Any]:
    """Run the benchmark, print the figures (or JSON with ``--json``) and return them."""
    parser = argument_parser(__doc__, runs=3)
    parser.add_argument("--devices", type=int, nargs="+", default=[1, 3, 6],
                        help="numbers of devices to serve (one run set each)")
    parser.add_argument("--seconds", type=float, default=3.0,
                        help="seconds of setpoints per device and run")
    args = parse_arguments(parser, argv)
    if not 0.1 <= args.seconds <= 600:
        parser.error(f"--seconds {args.seconds!r}: 0.1 to 600")
    if any(not 1 <= n <= 64 for n in args.devices):
        parser.error(f"--devices {args.devices!r}: each 1 to 64")
    figures = measure(device_counts=args.devices, seconds=args.seconds, runs=args.runs)
    return emit(figures, report, as_json=args.json)


if __name__ == "__main__":
    main(sys.argv[1:])
