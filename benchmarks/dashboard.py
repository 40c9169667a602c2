"""The web dashboard: latency from the devices to the pixel, the server's CPU while a page is
open, and memory over minutes of motion with a page open.

    python benchmarks/dashboard.py [--minutes 10] [--json]

``usbmotion web``'s application on the default simulated machine in real time, served by
uvicorn in this process (the server, the session and the simulated devices share it), and
its page in headless Chromium (``_dashboard_page.js``, playwright-core from
``tests/senders``). The machine homes, then runs demo 1 again and again:

- **CPU of the page**: this process's CPU (every thread: the server, the session, the
  simulated devices), as a share of one core, over a window with no page open and over the
  same length of motion with the page open; the difference is what serving the page costs
  (goal: at most 10 % of a core at its 60 pushes a second). Also at rest, the same way.
- **Latency to the pixel**: for every state of a running program the page receives (at rest
  the model is read ten times a second; nothing moves), the wall time of the frame
  painted after it, less the time the server sent it, plus how old the live model's
  picture was then (``age_s``: since it took the devices' last diagnostics line). Added to
  its 95th percentile: the longest a servo tick waits for the line that reports it (the
  live diagnostics period, 20 ms) and for the run's next look at the lines (10 ms), for the
  oldest tick a frame shows. Goal: at most 100 ms.
- **Memory**: this process's resident memory, and the page's JavaScript heap, when the page
  opened and after ``--minutes`` of motion (bound: neither grows by more than 20 MB).

The machine is shared and noisy: the CPU figures are the means over their windows.
"""

from __future__ import annotations

import json
import os
import shutil
import statistics
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

import uvicorn

from _common import argument_parser, emit, parse_arguments
from usbmotion.cli.run import default_machine
from usbmotion.host.config import load_config
from usbmotion.serving import listening_socket
from usbmotion.session.operator import Operator
from usbmotion.session.run import REQUEST_CHECK_S
from usbmotion.session.watch import LIVE_PERIOD_S
from usbmotion.sim.machine import connect_session
from usbmotion.sim.world import SimWorld
from usbmotion.web.app import create_app, page_built
from usbmotion.web.dashboard import Dashboard

HERE = Path(__file__).resolve().parent
PAGE = HERE / "_dashboard_page.js"
TOKEN = "benchmark-token-0123456789"
WINDOW_S = 30.0
"""The length of each CPU window."""
LATENCY_GOAL_MS = 100.0
CPU_GOAL = 0.10
MEMORY_BOUND_MB = 20.0


def _rss_mb() -> float:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    return float("nan")


def _cpu_share(window_s: float) -> float:
    """This process's CPU over the next ``window_s`` of wall time, as a share of a core."""
    cpu, wall = time.process_time(), time.monotonic()
    time.sleep(window_s)
    return (time.process_time() - cpu) / (time.monotonic() - wall)


class _Machine:
    """The dashboard on the default machine, served on a free port; demo 1 on repeat."""

    def __init__(self) -> None:
        config = load_config(default_machine())
        self.world = SimWorld(realtime=True)
        self.session = connect_session(config, world=self.world)
        self.operator = Operator(self.session, file="<web>")
        self.operator.on_idle = self.world.keep_pace
        self.dashboard = Dashboard(self.operator)
        self.dashboard.start()
        self.listener = listening_socket("127.0.0.1", 0)
        self.server = uvicorn.Server(uvicorn.Config(
            create_app(self.dashboard, token=TOKEN), log_level="warning", lifespan="off",
            ws="websockets-sansio", timeout_graceful_shutdown=2))
        self.thread = threading.Thread(target=self.server.run,
                                       kwargs={"sockets": [self.listener]})
        self.thread.start()
        while not self.server.started:
            time.sleep(0.01)
        self.url = f"http://127.0.0.1:{self.listener.getsockname()[1]}/?token={TOKEN}"
        self._repeat = threading.Event()
        self._looping = threading.Thread(target=self._loop, daemon=True)

    def home_and_open(self) -> None:
        self.dashboard.home()
        self._wait_idle()
        self.dashboard.open_demo(1)

    def _wait_idle(self) -> None:
        time.sleep(0.2)
        while self.operator.busy:
            time.sleep(0.05)

    def start_motion(self) -> None:
        self._repeat.set()
        self._looping.start()

    def _loop(self) -> None:
        while self._repeat.is_set():
            self.dashboard.run()
            self._wait_idle()

    def close(self) -> None:
        self._repeat.clear()
        self.operator.stop()
        self.server.should_exit = True
        self.thread.join(timeout=10)
        self.listener.close()
        self.dashboard.close()
        self.operator.close()
        self.session.shutdown()
        self.session.close()


def measure(minutes: float) -> dict[str, Any]:
    """The figures (see the module docstring)."""
    chromium = shutil.which("chromium") or "/usr/bin/chromium"
    if not page_built() or not Path(chromium).exists():
        raise SystemExit("dashboard.py needs the page (make web) and Chromium (make test"
                         " installs it: tests/senders/install.sh)")
    machine = _Machine()
    try:
        machine.home_and_open()
        rest_without = _cpu_share(WINDOW_S / 3)
        machine.start_motion()
        time.sleep(2.0)
        motion_without = _cpu_share(WINDOW_S)
        page = subprocess.Popen(["node", str(PAGE), machine.url, chromium],
                                stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
        try:
            assert page.stdout is not None and page.stdin is not None
            if page.stdout.readline().strip() != "ready":
                raise RuntimeError("the page did not open")
            rss_start = _rss_mb()
            motion_with = _cpu_share(WINDOW_S)
            time.sleep(max(0.0, minutes * 60 - WINDOW_S))
            rss_end = _rss_mb()
            machine._repeat.clear()
            machine.operator.stop()
            machine._wait_idle()
            time.sleep(1.0)
            rest_with = _cpu_share(WINDOW_S / 3)
            page.stdin.close()
            result = json.loads(page.stdout.readline())
            page.wait(timeout=30)
        finally:
            if page.poll() is None:
                page.kill()
                page.wait()
        before_read_s = LIVE_PERIOD_S + REQUEST_CHECK_S
    finally:
        machine.close()
    latencies_ms = sorted(v * 1000 for v in result["latency"])
    p95 = latencies_ms[int(0.95 * (len(latencies_ms) - 1))]
    heap_start, heap_end = result["heapStart"], result["heapEnd"]
    return {
        "minutes": minutes,
        "states_received": result["count"],
        "states_per_s": result["count"] / (minutes * 60 + WINDOW_S / 3 + 1.0),
        "latency_ms": {"median": statistics.median(latencies_ms), "p95": p95,
                       "max": latencies_ms[-1]},
        "line_to_host_ms": before_read_s * 1000,
        "cpu_share": {"rest_without_page": rest_without, "rest_with_page": rest_with,
                      "motion_without_page": motion_without, "motion_with_page": motion_with,
                      "page_at_rest": rest_with - rest_without,
                      "page_in_motion": motion_with - motion_without},
        "server_rss_mb": {"start": rss_start, "end": rss_end},
        "page_heap_mb": {"start": None if heap_start is None else heap_start / 2**20,
                         "end": None if heap_end is None else heap_end / 2**20},
        "cpus": os.cpu_count(),
    }


def _text(figures: dict[str, Any]) -> str:
    lat, cpu = figures["latency_ms"], figures["cpu_share"]
    rss, heap = figures["server_rss_mb"], figures["page_heap_mb"]
    worst = lat["p95"] + figures["line_to_host_ms"]
    latency_met = "met" if worst <= LATENCY_GOAL_MS else "NOT met"
    rss_growth = rss["end"] - rss["start"]
    heap_growth = (heap["end"] - heap["start"]) if heap["start"] is not None else float("nan")
    return "\n".join([
        f"dashboard: demo 1 on repeat for {figures['minutes']:g} min on the default machine"
        f" in real time, one page open in Chromium ({figures['cpus']} CPUs)",
        f"  states of the running program painted: {figures['states_received']:,}"
        f" ({figures['states_per_s']:.1f}/s over the whole time, rests included)",
        f"  live model to pixel: median {lat['median']:.1f} ms, p95 {lat['p95']:.1f} ms,"
        f" max {lat['max']:.1f} ms; with the longest a tick waits for its line and the host's"
        f" look ({figures['line_to_host_ms']:.0f} ms), the p95 from a tick to the pixel is"
        f" {worst:.1f} ms (goal {LATENCY_GOAL_MS:.0f} ms: {latency_met})",
        f"  CPU, share of a core: at rest {cpu['rest_without_page']:.3f} without the page,"
        f" {cpu['rest_with_page']:.3f} with it; in motion {cpu['motion_without_page']:.3f}"
        f" without, {cpu['motion_with_page']:.3f} with: the page costs"
        f" {cpu['page_at_rest'] * 100:.1f} % at rest, {cpu['page_in_motion'] * 100:.1f} % in"
        f" motion (goal {CPU_GOAL * 100:.0f} %:"
        f" {'met' if max(cpu['page_at_rest'], cpu['page_in_motion']) <= CPU_GOAL else 'NOT met'})",
        f"  memory: the server {rss['start']:.1f} -> {rss['end']:.1f} MB ({rss_growth:+.1f});"
        f" the page's heap {heap['start']:.1f} -> {heap['end']:.1f} MB ({heap_growth:+.1f})"
        f" (bound {MEMORY_BOUND_MB:.0f} MB each:"
        f" {'met' if max(rss_growth, heap_growth) <= MEMORY_BOUND_MB else 'NOT met'})",
    ])


def main(argv: list[str] | None = None) -> dict[str, Any]:
    parser = argument_parser(__doc__, runs=1)
    parser.add_argument("--minutes", type=float, default=10.0,
                        help="Minutes of motion with the page open (default 10).")
    args = parse_arguments(parser, argv)
    return emit(measure(args.minutes), _text, as_json=args.json)


if __name__ == "__main__":
    main(sys.argv[1:])
