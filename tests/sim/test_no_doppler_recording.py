"""`coplane simulate --no-doppler`: the same drive, its RINEX without Doppler (a receiver or stream
that gives none, e.g. RTCM MSM4)."""

from __future__ import annotations

import math
from pathlib import Path

from coplane.recording.reader import open_recording
from coplane.sim.generate import simulate


def test_the_same_drive_without_doppler(tmp_path: Path) -> None:
    a = open_recording(simulate("urban-loop", tmp_path / "a", vehicles=2, duration_s=5, seed=3))
    b = open_recording(
        simulate("urban-loop", tmp_path / "b", vehicles=2, duration_s=5, seed=3, doppler=False)
    )
    for f in (b.manifest.root / "vehicles" / "u1.obs", b.manifest.root / "base" / "ref.obs"):
        types = [line for line in f.read_text().splitlines() if "SYS / # / OBS TYPES" in line]
        assert types and not any(" D" in line[:60] for line in types), types
    assert not b.problems.counts
    for ea, eb in zip(a.vehicle_epochs("u1"), b.vehicle_epochs("u1"), strict=True):
        assert [s.sat for s in ea.sats] == [s.sat for s in eb.sats]
        for sa, sb in zip(ea.sats, eb.sats, strict=True):
            assert sa.pseudorange_m == sb.pseudorange_m and sa.cn0_dbhz == sb.cn0_dbhz
            assert math.isfinite(sa.doppler_hz) and math.isnan(sb.doppler_hz)
