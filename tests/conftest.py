"""Fixtures shared by the test modules."""

from __future__ import annotations

import threading
from collections.abc import Iterator

import pytest

from usbmotion.sim import drop_world


@pytest.fixture
def world_name() -> Iterator[str]:
    """A registered world name, unique to the test, dropped afterwards."""
    name = f"test-{threading.get_ident()}-{id(object())}"
    yield name
    drop_world(name)
