"""Why an epoch has no SPP fix, as the `spp` table and the node message say it."""

from __future__ import annotations

from pathlib import Path

from coplane.gnss.measurements import prepare_epoch
from coplane.gnss.spp import solve_spp
from coplane.recording.model import NavData, ObsEpoch
from coplane.recording.reader import open_recording

BUNDLED = Path(__file__).resolve().parents[2] / "shared/coplane/data/recordings/default"


def test_a_receiver_without_ephemerides_is_told_apart_from_a_poor_sky() -> None:
    """Satellites tracked but without an ephemeris (a navigation file of another day) give their
    own reason, with how many; an epoch that tracks only three gives the plain one."""
    rec = open_recording(BUNDLED)
    epoch = next(iter(rec.vehicle_epochs(rec.manifest.vehicles[0].id)))
    n = len([s for s in epoch.sats if s.sat[0] in "GC"])
    none = solve_spp(prepare_epoch(epoch, NavData()), NavData())
    assert (
        not none.ok
        and none.reason == f"too few satellites with an ephemeris: 0 < 4 ({n} tracked without one)"
    )
    three = ObsEpoch(epoch.time, epoch.sats[:3])
    few = solve_spp(prepare_epoch(three, rec.nav), rec.nav)
    assert not few.ok and few.reason == "too few satellites: 3 < 4"
