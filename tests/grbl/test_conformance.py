"""The front against grbl 1.1h's documented exchanges, byte for byte (tests/grbl/recorded.py)."""

from __future__ import annotations

import pytest
from tests.grbl.conformance import Exchange, replay
from tests.grbl.recorded import EXCHANGES


@pytest.mark.parametrize("exchange", EXCHANGES, ids=[e.name for e in EXCHANGES])
def test_exchange(exchange: Exchange) -> None:
    assert replay(exchange) == []
