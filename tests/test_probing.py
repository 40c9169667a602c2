"""The probe input of a machine file's simulated axis (``sim.probe_below_mm``: a plate under a
Z probe), sent to its device by call 40: moved onto the plate, the device latches the count
of contact (call 41) at the plate's height to the count, however long the host takes to
look; lifted off, the input opens again."""

from __future__ import annotations

from pathlib import Path

import pytest

from usbmotion.cli.machines import default_machine
from usbmotion.errors import ConfigError
from usbmotion.host.config import load_config
from usbmotion.sim.machine import connect_session

PLATE_MM = -20.0


def _machine_with_plate(folder: Path, probe: str = f"probe_below_mm = {PLATE_MM}") -> Path:
    text = default_machine().read_text()
    old = "sim = { start_mm = -50.0"
    assert old in text, "the default machine's Z no longer starts at -50 mm"
    path = folder / "plate.toml"
    path.write_text(text.replace(old, f"sim = {{ {probe}, start_mm = -50.0", 1))
    return path


def test_a_plate_under_z_latches_the_contact_at_its_height(tmp_path: Path) -> None:
    config = load_config(_machine_with_plate(tmp_path))
    z = config.axis("Z")
    assert z.sim is not None and (z.sim.probe_side, z.sim.probe_mm) == (1, PLATE_MM)
    with connect_session(config) as session:
        session.home()
        client = session.machine.axis("Z").client
        assert client.sim_probe() == z.sim_probe_counts
        before = client.probe()  # homing lifted Z off the plate it powered up under
        assert not before.closed and before.edges == 1, "Z at the top, far above the plate"
        session.jog({"Z": PLATE_MM - 2.0}, feed_mm_min=120, absolute=True)
        touched = client.probe()
        assert touched.closed and touched.edges == 2 and touched.edge_closed
        contact_mm = session.machine.axis("Z").scale.to_mm(touched.position_counts)
        assert contact_mm == pytest.approx(PLATE_MM, abs=1.5 / z.counts_per_mm), (
            "the first count at or below the plate, at 2 mm/s (a count a tick is 4 mm/s)")
        session.jog({"Z": PLATE_MM + 5.0}, feed_mm_min=600, absolute=True)
        lifted = client.probe()
        assert not lifted.closed and lifted.edges == 3 and not lifted.edge_closed
        for name in ("X", "Y"):
            assert session.machine.axis(name).client.probe().edges == 0, "no plate there"


def test_a_probe_surface_is_one_and_within_the_travel(tmp_path: Path) -> None:
    both = _machine_with_plate(tmp_path, "probe_below_mm = -20.0, probe_above_mm = -10.0")
    with pytest.raises(ConfigError, match=r"probe_below_mm .* or probe_above_mm, not both"):
        load_config(both)
    beyond = _machine_with_plate(tmp_path, "probe_below_mm = -120.0")
    with pytest.raises(ConfigError, match=r"axes\.Z\.sim\.probe_below_mm: -120"):
        load_config(beyond)
