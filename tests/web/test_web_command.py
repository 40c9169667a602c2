"""``usbmotion web`` as a user starts it: bound beyond 127.0.0.1 it prints its address and
refuses every API call without the token; SIGTERM while a program runs stops the machine
and exits 0; a port in use is a clear error."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
import urllib.error
import urllib.request
from pathlib import Path
from typing import Any

import pytest
from tests.senders.helpers import fast_homing_machine

from usbmotion.serving import listening_socket

pytestmark = pytest.mark.realtime

START_TIMEOUT_S = 120.0
"""A cold numba cache on a loaded machine takes tens of seconds to compile the kernel."""


def _call(url: str, *, token: str | None = None, body: object = None) -> tuple[int, Any]:
    request = urllib.request.Request(
        url, method="GET" if body is None else "POST",
        data=None if body is None else json.dumps(body).encode())
    if token is not None:
        request.add_header("Authorization", f"Bearer {token}")
    try:
        with urllib.request.urlopen(request, timeout=10) as response:
            return response.status, json.loads(response.read())
    except urllib.error.HTTPError as error:
        return error.code, json.loads(error.read())


def _started(process: subprocess.Popen[str]) -> str:
    assert process.stdout is not None
    deadline = time.monotonic() + START_TIMEOUT_S
    while time.monotonic() < deadline:
        line = process.stdout.readline()
        if " at http://" in line:
            return line.split(" at ", 1)[1].split()[0]
        if not line and process.poll() is not None:
            break
    raise AssertionError(f"usbmotion web did not print its address: {process.poll()}")


def test_bound_beyond_loopback_it_needs_the_token_and_sigterm_stops_it(tmp_path: Path) -> None:
    machine = fast_homing_machine(tmp_path)
    process = subprocess.Popen(
        [sys.executable, "-m", "usbmotion", "web", "--host", "0.0.0.0", "--port", "0",
         "--machine", str(machine)],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=os.environ.copy())
    try:
        address = _started(process)
        base, _, token = address.partition("/?token=")
        base = base.replace("0.0.0.0", "127.0.0.1")
        assert len(token) >= 16
        for path in ("/api/state", "/api/program", "/api/devices"):
            status, answer = _call(base + path)
            assert status == 401 and "token" in answer["error"], path
        status, answer = _call(base + "/api/home", body={})
        assert status == 401
        status, answer = _call(base + "/api/state", token=token)
        assert status == 200 and answer["state"] == "Idle" and not answer["homed"]
        assert _call(base + "/api/program/open", token=token, body={"demo": 1})[0] == 200
        # The command hands the page its predictor: demo 1 on the axes' sim tables.
        status, answer = _call(base + "/api/predict", token=token, body={"tolerance_mm": 1})
        assert status == 200 and answer["completed"], answer
        assert [a["name"] for a in answer["axes"]] == ["X", "Y", "Z"]
        assert all(a["max_error_counts"] > 0 for a in answer["axes"]), answer["axes"]
        assert _call(base + "/api/run", token=token, body={})[0] == 200
        deadline = time.monotonic() + 60
        while _call(base + "/api/state", token=token)[1]["state"] != "Run":
            assert time.monotonic() < deadline, "the run did not start"
            time.sleep(0.05)
        time.sleep(0.5)
        process.send_signal(signal.SIGTERM)
        _, errors = process.communicate(timeout=30)
        assert process.returncode == 0, errors
        assert "stopping the machine" in errors
    finally:
        if process.poll() is None:
            process.kill()
            process.communicate()


def test_a_port_in_use_is_a_clear_error(tmp_path: Path) -> None:
    taken = listening_socket("127.0.0.1", 0)
    try:
        port = taken.getsockname()[1]
        done = subprocess.run(
            [sys.executable, "-m", "usbmotion", "web", "--port", str(port), "--machine",
             str(fast_homing_machine(tmp_path))],
            check=False, capture_output=True, text=True, timeout=120, env=os.environ.copy())
    finally:
        taken.close()
    assert done.returncode == 2
    assert f"cannot listen on 127.0.0.1:{port}" in done.stderr
    assert "Traceback" not in done.stderr
