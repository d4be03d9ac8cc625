"""Convert a fleet recording's observations to receiver formats: UBX or RTCM 3 (`coplane convert`).

For tests (the same data through another reader must give the same positions) and for users
who have logs: each vehicle becomes vehicles/<id>.ubx (RXM-RAWX) or vehicles/<id>.rtcm3 (MSM7,
or MSM4-6 as asked, with 1019/1042 first), the base becomes base/<name>.rtcm3 (a reference station speaks RTCM),
uwb.csv and truth/ are copied, and a fleet.toml points at them. Navigation:
* RTCM 3: nav/ephemerides.rtcm3 (1019/1042 only) first, then nav/iono.rnx, a RINEX header with
  the Klobuchar coefficients only, because RTCM 3 has no ionosphere message;
* UBX: nav/ephemerides.ubx, the GPS ephemerides as RXM-SFRBX LNAV subframes 1-3 and the GPS
  Klobuchar coefficients as subframe 4 page 18 (recording/sfrbx.py); BeiDou D1/D2 has no SFRBX
  encoder here, so the original RINEX files follow it for BeiDou. Each vehicle's .ubx also
  starts with the GPS SFRBX subframes, as a receiver log would.
After writing, the result is read back and compared with the source, epoch by epoch and
satellite by satellite, so the cost of the format is measured, not assumed.
"""

from __future__ import annotations

import math
import shutil
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

from coplane.recording.manifest import write_manifest
from coplane.recording.model import BaseSpec, Manifest, NavData, ObsEpoch, UwbSpec, VehicleSpec
from coplane.recording.output_dir import prepare_output
from coplane.recording.problems import RecordingError
from coplane.recording.reader import Recording, open_recording
from coplane.recording.rtcm3 import (
    C_LIGHT,
    CNR_LSB_DBHZ,
    FREQ_HZ,
    MSM_IDS,
    PSEUDORANGE_LSB_M,
    RATE_LSB_MPS,
    msm_extended,
    msm_rates,
    write_rtcm3,
)
from coplane.recording.sfrbx import write_sfrbx_nav
from coplane.recording.ubx import write_ubx
from coplane.recording.writer import write_nav

Format = Literal["ubx", "rtcm3"]
FORMATS: tuple[str, ...] = ("ubx", "rtcm3")

UBX_RESOLUTION = (
    "UBX RXM-RAWX: pseudorange and carrier phase are doubles (exact); Doppler is a float32 "
    "(<= 2.4e-4 Hz below 4096 Hz); C/N0 is whole dB-Hz (rounded, <= 0.5 dB); epoch tags are doubles (exact)"
)


def rtcm_resolution(msm: int) -> str:
    """What an MSM level keeps of the observations (rtcm3.py's module docstring has the fields)."""
    lsb_m = PSEUDORANGE_LSB_M if msm_extended(msm) else PSEUDORANGE_LSB_M * 32  # 2^-29 or 2^-24 ms
    doppler = (
        f"phase-range rate LSB {RATE_LSB_MPS} m/s (Doppler <= 2.6e-4 Hz on L1/B1I)"
        if msm_rates(msm)
        else "no Doppler"
    )
    cn0 = f"{CNR_LSB_DBHZ} dB-Hz" if msm_extended(msm) else "1 dB-Hz"
    return (
        f"RTCM 3 MSM{msm}: pseudorange LSB {lsb_m * 1e3:.3f} mm (rounding <= {lsb_m * 500:.3f} mm); "
        f"{doppler}; C/N0 LSB {cn0}; epoch tags whole ms (a sub-ms tag is moved to the ms along each Doppler)"
    )


@dataclass
class ObsDifference:
    """Largest differences of a read-back file against the source (same satellites, same epochs)."""

    name: str
    epochs_source: int = 0
    epochs_read: int = 0
    satellites_missing: int = 0
    max_pseudorange_m: float = 0.0
    max_doppler_hz: float = 0.0
    max_cn0_dbhz: float = 0.0
    max_carrier_cycles: float = 0.0


@dataclass
class ConvertResult:
    out: Path
    fmt: str
    resolution: str
    differences: list[ObsDifference] = field(default_factory=list)
    skipped: list[str] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    problems: int = 0


def _diff(name: str, src: list[ObsEpoch], got: list[ObsEpoch], interval: float) -> ObsDifference:
    d = ObsDifference(name, len(src), len(got))
    by_t = {e.time.round_to(interval): e for e in got}
    for e in src:
        g = by_t.get(e.time.round_to(interval))
        if g is None:
            d.satellites_missing += len(e.sats)
            continue
        shift = e.time - g.time  # RTCM moves a sub-ms tag to the millisecond, along each rate
        gs = g.by_sat()
        for s in e.sats:
            o = gs.get(s.sat)
            if o is None:
                d.satellites_missing += 1
                continue
            dop = s.doppler_hz if math.isfinite(s.doppler_hz) else 0.0
            lam = C_LIGHT / FREQ_HZ[s.sat[0]]
            expected = s.pseudorange_m + shift * lam * dop
            d.max_pseudorange_m = max(d.max_pseudorange_m, abs(o.pseudorange_m - expected))
            d.max_doppler_hz = _max_finite(d.max_doppler_hz, o.doppler_hz - s.doppler_hz)
            d.max_cn0_dbhz = _max_finite(d.max_cn0_dbhz, o.cn0_dbhz - s.cn0_dbhz)
            if math.isfinite(s.carrier_cycles):
                d.max_carrier_cycles = _max_finite(
                    d.max_carrier_cycles, o.carrier_cycles - (s.carrier_cycles + shift * dop)
                )
    return d


def _max_finite(cur: float, v: float) -> float:
    return max(cur, abs(v)) if math.isfinite(v) else cur


def _copy(src: Path, root: Path, out: Path) -> Path:
    rel = src.resolve().relative_to(root)
    dst = out / rel
    dst.parent.mkdir(parents=True, exist_ok=True)
    shutil.copyfile(src, dst)
    return dst


def _nav_files(rec: Recording, fmt: str, out: Path, result: ConvertResult) -> tuple[Path, ...]:
    m = rec.manifest
    nav = rec.nav
    if fmt == "rtcm3":
        iono = out / "nav" / "iono.rnx"
        write_nav(iono, NavData(iono=dict(nav.iono)))
        rep = write_rtcm3(out / "nav" / "ephemerides.rtcm3", [], nav)
        result.skipped += [f"nav: {s}" for s in rep.skipped]
        return (out / "nav" / "ephemerides.rtcm3", iono)
    path = out / "nav" / "ephemerides.ubx"
    not_written = write_sfrbx_nav(path, nav)
    if not not_written:
        return (path,)
    # BeiDou D1/D2 has no SFRBX encoder here: the original RINEX files follow for it (their GPS
    # records duplicate the SFRBX ones, which come first and win)
    result.notes.append(
        f"{len(not_written)} ephemeris record(s) not in RXM-SFRBX (BeiDou): kept the RINEX nav"
    )
    return (path, *(_copy(p, m.root, out) for p in m.nav_files))


FORMAT_NAMES = {"ubx": "UBX", "rtcm3": "RTCM 3"}  # in a conversion's name, in brackets
CONVERTED_PARTS = ("vehicles", "base", "nav")  # what every conversion writes besides its copies


def convert_recording(source: str | Path, fmt: Format, out: str | Path, msm: int = 7) -> ConvertResult:
    """Write `source` as a UBX or RTCM 3 recording in `out`, read it back and measure the difference.
    `msm`: the RTCM 3 MSM level of the observations (4-7; MSM4 and MSM6 carry no Doppler)."""
    if fmt not in FORMATS:
        raise RecordingError(f"unknown format {fmt!r} (expected one of {', '.join(FORMATS)})")
    if msm not in MSM_IDS:
        raise RecordingError(f"MSM{msm}: the RTCM 3 MSM level is 4 to 7")
    if fmt == "ubx" and msm != 7:
        raise RecordingError(f"MSM{msm} asked for a UBX conversion: the MSM level is for RTCM 3 only")
    rec = open_recording(source)
    m = rec.manifest
    out = Path(out).resolve()
    if out == m.root or out.is_relative_to(m.root):
        raise RecordingError(f"{out}: the output must not be inside the source recording {m.root}")
    prepare_output(out, "convert", CONVERTED_PARTS)
    result = ConvertResult(out, fmt, UBX_RESOLUTION if fmt == "ubx" else rtcm_resolution(msm))

    vehicles: list[VehicleSpec] = []
    for station, v in enumerate(m.vehicles, start=1):
        path = out / "vehicles" / f"{v.id}.{fmt}"
        epochs = rec.vehicle_epochs(v.id)
        if fmt == "ubx":
            write_ubx(path, epochs, nav=rec.nav)
        else:
            rep = write_rtcm3(path, epochs, rec.nav, station=station, msm=msm)
            result.skipped += [f"{v.id}: {s}" for s in rep.skipped]
        truth = _copy(v.truth, m.root, out) if v.truth is not None else None
        vehicles.append(VehicleSpec(v.id, path, v.antenna_height_m, truth))
    base = None
    if m.base is not None:
        path = out / "base" / f"{m.base.obs.stem}.rtcm3"
        rep = write_rtcm3(path, rec.base_epochs(), rec.nav, station=0, msm=msm)
        result.skipped += [f"base: {s}" for s in rep.skipped]
        base = BaseSpec(path, m.base.position_ecef_m)
    uwb = None
    if m.uwb is not None:
        uwb = UwbSpec(_copy(m.uwb.file, m.root, out), m.uwb.sigma_m, m.uwb.max_range_m)
    nav_files = _nav_files(rec, fmt, out, result)
    name = f"{m.name} ({FORMAT_NAMES[fmt]})"
    write_manifest(Manifest(out, name, m.interval_s, nav_files, tuple(vehicles), base, uwb))

    back = open_recording(out)
    for v in m.vehicles:
        result.differences.append(
            _diff(v.id, rec.vehicle_epochs(v.id), back.vehicle_epochs(v.id), m.interval_s)
        )
    if m.base is not None:
        result.differences.append(_diff("base", rec.base_epochs(), back.base_epochs(), m.interval_s))
    back.nav  # noqa: B018  read the navigation files too, so their problems count
    result.problems = back.problems.total
    return result
