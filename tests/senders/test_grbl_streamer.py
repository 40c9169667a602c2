"""grbl-streamer (PyPI) against the grbl server on a pseudo-terminal, with the fake machine:
it connects, unlocks, homes, streams a program with character counting and reports it done;
the receive buffer never overflows and the machine's path is the program's."""

from __future__ import annotations

import importlib.util
import threading
import time
from typing import Any

from tests.grbl.conformance import path_problems
from tests.senders.helpers import PROGRAM, PROGRAM_PATH, need, served_fake, wait_for


def test_grbl_streamer_homes_and_streams_a_program() -> None:
    need(importlib.util.find_spec("grbl_streamer") is not None, "grbl-streamer (PyPI)")
    from grbl_streamer import GrblStreamer  # type: ignore[import-untyped]  # noqa: PLC0415

    events: list[tuple[str, tuple[Any, ...]]] = []
    lock = threading.Lock()
    start_job = threading.Event()

    def callback(event: str, *data: Any) -> None:
        with lock:
            events.append((event, data))
        # grbl-streamer streams from the caller of job_run and from its reader thread on
        # each ok, unguarded: started from another thread, a line can go out twice. So the
        # job starts here, on its reader thread, after an ok.
        if event == "on_rx_buffer_percent" and start_job.is_set():
            start_job.clear()
            streamer.job_run()

    def seen(event: str, *data: Any) -> bool:
        with lock:
            return any(e == event and d[:len(data)] == data for e, d in events)

    with served_fake() as (server, machine):
        streamer = GrblStreamer(callback)
        streamer.setup_logging()
        streamer.cnect(server.path, 115200)
        try:
            wait_for(lambda: seen("on_boot"), timeout_s=5, what="grbl-streamer's on_boot")
            streamer.poll_start()
            streamer.killalarm()
            streamer.homing()
            wait_for(lambda: machine.homings == 1, timeout_s=5, what="homing")
            time.sleep(0.3)  # the $H's ok taken before the job counts characters
            streamer.incremental_streaming = False  # character counting
            streamer.write(PROGRAM)
            start_job.set()
            streamer.send_immediately("G4 P0")  # its ok starts the job
            wait_for(lambda: seen("on_job_completed") and streamer.job_finished
                     and streamer.streaming_complete, timeout_s=20, what="the job's end")
            wait_for(lambda: seen("on_stateupdate", "Idle", (0.0, 0.0, 1.0)), timeout_s=10,
                     what="the report of the machine at rest at the program's end")
        finally:
            streamer.disconnect()
        errors = [data for event, data in events if event in ("on_error", "on_alarm")]
        assert errors == []
        statistics = server.protocol.statistics
        print(f"grbl-streamer: the receive buffer held at most {statistics.max_rx_bytes} bytes"
              f" of 128, {statistics.dropped_rx_bytes} dropped")
        assert statistics.dropped_rx_bytes == 0
        assert 0 < statistics.max_rx_bytes <= 128
        assert path_problems([d.target_mm for d in machine.done], PROGRAM_PATH) == [], machine.done
