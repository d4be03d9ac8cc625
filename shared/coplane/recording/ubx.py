"""u-blox UBX observation files: RXM-RAWX in and out, through pyubx2.

Reading gives the same `ObsEpoch` / `SatObservation` model as the RINEX reader: satellite ids
"G05" / "C12", the one signal per system that `SignalCodes` selects (GPS L1 C/A = RAWX sigId 0,
BeiDou B1I = sigId 0 (D1) or 1 (D2)), metres, Hz (RINEX sign: u-blox's doMes is positive for
approaching satellites too), dB-Hz and cycles, and the same validity rules (pseudorange within
1.5e7..5e7 m, SNR 0..70 dB-Hz; `prValid` = 0 drops the satellite, `cpValid` = 0 drops the phase).

Time: rcvTow (double, seconds) and week (16 bits, rollover already resolved by the receiver) are
the receiver's own GPST tag, used as is; leapS (GPS - UTC) is written from `leap_seconds` and
not needed to read GPST. The RINEX epoch flag 1 (power failure) is carried as recStat.clkReset.

What RAWX costs against RINEX (F14.3 fields):
* pseudorange and carrier are doubles: bit-exact;
* doMes is a float32: 24-bit mantissa, so |D| < 4096 Hz is kept to 2.4e-4 Hz (0.05 mm/s on
  L1), |D| < 8192 Hz to 4.9e-4 Hz;
* cno is an integer dB-Hz: C/N0 is rounded to 1 dB-Hz (up to 0.5 dB), which changes the C/N0
  term of coplane's measurement weights (gnss/weighting.py), so UBX positions equal RINEX ones
  bit for bit only when the RINEX C/N0 is already whole (tests/recording/test_convert.py
  measures both).
RAWX has no field for the receiver clock offset RINEX may carry; it is not written.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

from pyubx2 import GET, UBXMessage, UBXReader

from coplane.gtime import GpsTime
from coplane.recording.compressed import read_log_bytes
from coplane.recording.frames import Frame, ubx_frames
from coplane.recording.lock_time import LockTimer
from coplane.recording.model import NavData, ObsEpoch, ObsHeader, SatObservation
from coplane.recording.problems import Problems, RecordingError
from coplane.recording.rinex_obs import (
    DEFAULT_SIGNALS,
    DEFAULT_SYSTEMS,
    PSEUDORANGE_MAX_M,
    PSEUDORANGE_MIN_M,
    SNR_MAX_DBHZ,
    SNR_MIN_DBHZ,
    SignalCodes,
)

GNSS_ID: dict[str, int] = {"G": 0, "C": 3}  # u-blox gnssId
SYSTEM_OF: dict[int, str] = {v: k for k, v in GNSS_ID.items()}
# RINEX pseudorange code -> RAWX sigIds (u-blox interface description, "signal identifiers").
SIG_IDS: dict[tuple[str, str], tuple[int, ...]] = {
    ("G", "C1C"): (0,),
    ("G", "C2L"): (3,),
    ("G", "C2S"): (4,),
    ("G", "C5I"): (6,),
    ("G", "C5Q"): (7,),
    ("C", "C2I"): (0, 1),  # B1I D1 (MEO/IGSO), D2 (GEO)
    ("C", "C1I"): (0, 1),  # RINEX 3.02 name of B1I
    ("C", "C7I"): (2, 3),  # B2I D1, D2
}
# GPS - UTC (s) from these GPST instants on (IERS bulletin C); RAWX leapS.
_LEAPS: tuple[tuple[GpsTime, int], ...] = (
    (GpsTime.from_calendar(1999, 1, 1), 13),
    (GpsTime.from_calendar(2006, 1, 1, 0, 0, 13), 14),
    (GpsTime.from_calendar(2009, 1, 1, 0, 0, 14), 15),
    (GpsTime.from_calendar(2012, 7, 1, 0, 0, 15), 16),
    (GpsTime.from_calendar(2015, 7, 1, 0, 0, 16), 17),
    (GpsTime.from_calendar(2017, 1, 1, 0, 0, 17), 18),
)
SFRBX_CLASS_ID = b"\x02\x13"  # RXM-SFRBX's class and id bytes: navigation subframes (recording/sfrbx.py)
_RAWX_HEAD = 16  # bytes before the repeated measurement blocks
MAX_LOCKTIME_MS = 64500  # RAWX locktime saturates here
# Nominal standard deviations written to RAWX: coplane keeps no per-measurement sigma.
_PR_STD, _CP_STD, _DO_STD = 5, 2, 4  # 0.01*2^5 = 0.32 m, 0.008 cycles, 0.002*2^4 = 0.032 Hz


def leap_seconds(t: GpsTime) -> int | None:
    """GPS - UTC at GPST t (None before 1999, where coplane keeps no table)."""
    out = None
    for start, n in _LEAPS:
        if t >= start:
            out = n
    return out


def _sig_ids(sys: str, sig: SignalCodes) -> tuple[int, ...]:
    try:
        return SIG_IDS[(sys, sig.pseudorange)]
    except KeyError:
        raise ValueError(f"no RAWX signal for {sys} {sig.pseudorange}: known {sorted(SIG_IDS)}") from None


# --------------------------------------------------------------------------------------------
# Writing


def rawx_message(
    ep: ObsEpoch, signals: Mapping[str, SignalCodes], lock: LockTimer | None = None
) -> UBXMessage:
    """One epoch as RXM-RAWX (satellites of systems without a RAWX signal are an error).

    pyubx2 builds the header and each 32-byte measurement block (a one-measurement RAWX each) and
    parses the joined payload: building one message from a few hundred keywords at once costs
    pyubx2 time quadratic in their number (25 ms an epoch; this way about 3 ms).
    """
    lock = lock or LockTimer()
    leap = leap_seconds(ep.time)
    head = {
        "rcvTow": ep.time.tow,
        "week": ep.time.week,
        "leapS": leap if leap is not None else 0,
        "leapSec": 1 if leap is not None else 0,
        "clkReset": 1 if ep.flag == 1 else 0,
    }
    blocks = []
    for s in ep.sats:
        sys = s.sat[0]
        if sys not in GNSS_ID or sys not in signals:
            raise ValueError(f"satellite {s.sat}: system {sys} cannot be written to RXM-RAWX")
        has_cp = math.isfinite(s.carrier_cycles)
        cno = 0 if not math.isfinite(s.cn0_dbhz) else max(0, min(255, round(s.cn0_dbhz)))
        one = UBXMessage(
            "RXM",
            "RXM-RAWX",
            GET,
            numMeas=1,
            prMes_01=s.pseudorange_m,
            cpMes_01=s.carrier_cycles if has_cp else 0.0,
            doMes_01=s.doppler_hz,  # NaN stays NaN: "not measured"
            gnssId_01=GNSS_ID[sys],
            svId_01=int(s.sat[1:]),
            sigId_01=_sig_ids(sys, signals[sys])[0],
            locktime_01=min(MAX_LOCKTIME_MS, lock.ms(s.sat, ep.time, has_cp)),
            cno_01=cno,
            prStd_01=_PR_STD,
            cpStd_01=_CP_STD,
            doStd_01=_DO_STD,
            prValid_01=1,
            cpValid_01=1 if has_cp else 0,
        )
        blocks.append(one.payload[_RAWX_HEAD:])
    header = UBXMessage("RXM", "RXM-RAWX", GET, numMeas=len(blocks), **head).payload[:_RAWX_HEAD]
    return UBXMessage("RXM", "RXM-RAWX", GET, payload=header + b"".join(blocks))


def write_ubx(
    path: str | Path,
    epochs: Iterable[ObsEpoch],
    signals: Mapping[str, SignalCodes] | None = None,
    nav: NavData | None = None,
) -> Path:
    """Write one RXM-RAWX per epoch (GPS and BeiDou, the selected signal of each), after the
    ephemerides of `nav` as RXM-SFRBX subframes when given (as a receiver logs them)."""
    sig = dict(DEFAULT_SIGNALS if signals is None else signals)
    lock = LockTimer()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("wb") as f:
        if nav is not None:
            from coplane.recording.sfrbx import ephemeris_messages

            for ephs in nav.ephemerides.values():
                for e in ephs:
                    if e.system in ("G", "C"):
                        f.write(b"".join(m.serialize() for m in ephemeris_messages(e, nav.iono.get("C"))))
        for ep in epochs:
            f.write(rawx_message(ep, sig, lock).serialize())
    return path


# --------------------------------------------------------------------------------------------
# Reading


class RawxReader:
    """RXM-RAWX frames -> epochs, one frame at a time (the file reader and live streams)."""

    def __init__(
        self, path: str | Path, problems: Problems, signals: Mapping[str, SignalCodes], systems: Sequence[str]
    ) -> None:
        self.path = path
        self.problems = problems
        self.wanted: dict[tuple[int, int], str] = {}  # (gnssId, sigId) -> system
        self.codes: dict[str, SignalCodes] = {}
        for sys in systems:
            if sys in GNSS_ID and sys in signals:
                self.codes[sys] = signals[sys]
                for sid in _sig_ids(sys, signals[sys]):
                    self.wanted[(GNSS_ID[sys], sid)] = sys
        self.last: GpsTime | None = None

    def _p(self, offset: int, kind: str, reason: str) -> None:
        self.problems.add(self.path, None, kind, reason, offset=offset)

    def epoch(self, fr: Frame) -> ObsEpoch | None:
        try:
            msg = UBXReader.parse(fr.raw)
        except Exception as exc:  # pyubx2 raises its own types, struct.error, ValueError, ...
            self._p(fr.offset, "malformed-frame", f"UBX frame does not decode: {exc}")
            return None
        if msg.identity != "RXM-RAWX":
            return None  # other UBX messages (NAV-PVT, SFRBX, ...) are not observations
        tow, week = float(msg.rcvTow), int(msg.week)
        if not (math.isfinite(tow) and 0.0 <= tow < 604800.0):
            self._p(fr.offset, "malformed-epoch", f"RXM-RAWX rcvTow {tow} outside a week: skipped")
            return None
        t = GpsTime(week, tow)
        if self.last is not None and t <= self.last:
            self._p(fr.offset, "non-monotonic-time", f"epoch {t} is not after {self.last}: skipped")
            return None
        self.last = t
        sats: list[SatObservation] = []
        seen: set[str] = set()
        for i in range(1, int(msg.numMeas) + 1):
            s = self._sat(msg, f"_{i:02d}", fr.offset)
            if s is None:
                continue
            if s.sat in seen:
                self._p(fr.offset, "duplicate-satellite", f"{s.sat} twice in epoch {t}: kept the first")
                continue
            seen.add(s.sat)
            sats.append(s)
        return ObsEpoch(t, tuple(sats), 1 if msg.clkReset else 0)

    def _sat(self, msg: UBXMessage, k: str, offset: int) -> SatObservation | None:
        sys = self.wanted.get((getattr(msg, "gnssId" + k), getattr(msg, "sigId" + k)))
        if sys is None or not getattr(msg, "prValid" + k):
            return None
        sat = f"{sys}{int(getattr(msg, 'svId' + k)):02d}"
        pr = float(getattr(msg, "prMes" + k))
        if not (PSEUDORANGE_MIN_M <= pr <= PSEUDORANGE_MAX_M):  # also catches NaN
            self._p(offset, "absurd-value", f"{sat}: pseudorange {pr} m outside 1.5e7..5e7 m")
            return None
        code = self.codes[sys]
        dop = float(getattr(msg, "doMes" + k)) if code.doppler is not None else math.nan
        if not math.isfinite(dop):
            dop = math.nan
        cn0 = math.nan
        if code.snr is not None:
            c = float(getattr(msg, "cno" + k))
            if c != 0.0:
                if SNR_MIN_DBHZ <= c <= SNR_MAX_DBHZ:
                    cn0 = c
                else:
                    self._p(offset, "absurd-value", f"{sat}: C/N0 {c} dB-Hz outside 0..70")
        cp = math.nan
        if code.carrier is not None and getattr(msg, "cpValid" + k):
            cp = float(getattr(msg, "cpMes" + k))
            if not math.isfinite(cp):
                cp = math.nan
        return SatObservation(sat, pr, dop, cn0, cp)


@dataclass
class UbxLog:
    """One pass over a UBX log: its RXM-RAWX epochs and its RXM-SFRBX frames. A u-blox log
    usually carries both, and a recording takes it as a vehicle's observations and as a
    navigation source (`coplane.recording.logs`): read once, its damage is counted once."""

    path: Path
    header: ObsHeader
    epochs: list[ObsEpoch]
    sfrbx: list[Frame]  # for `sfrbx.read_sfrbx_nav(frames=...)`
    damaged: bool  # problems had been reported when it was read

    def observations(self) -> tuple[ObsHeader, list[ObsEpoch]]:
        """Its epochs; RecordingError when it has none and nothing was damaged (not a raw log)."""
        if not self.epochs and not self.damaged:
            raise RecordingError(f"{self.path}: no UBX RXM-RAWX message (not a u-blox raw observation log)")
        return self.header, self.epochs


def log_frames(path: Path, problems: Problems) -> Iterator[Frame]:
    """The UBX frames of a log (.ubx, or archived: .ubx.gz); the bytes between them are reported
    with their offset, except NMEA text, which is another protocol, not damage."""
    for item in ubx_frames(read_log_bytes(path, "UBX")):
        if isinstance(item, Frame):
            yield item
        elif not item.ascii:
            problems.add(
                path,
                None,
                "garbled-frame",
                f"{item.length} byte(s) skipped: {item.reason}",
                offset=item.offset,
            )


def parse_ubx(
    path: str | Path,
    problems: Problems,
    signals: Mapping[str, SignalCodes] | None = None,
    systems: Sequence[str] = DEFAULT_SYSTEMS,
) -> UbxLog:
    """A UBX log read once for its observations and its navigation subframes."""
    path = Path(path)
    rd = RawxReader(path, problems, dict(DEFAULT_SIGNALS if signals is None else signals), systems)
    epochs: list[ObsEpoch] = []
    sfrbx: list[Frame] = []
    for fr in log_frames(path, problems):
        if fr.raw[2:4] == SFRBX_CLASS_ID:
            sfrbx.append(fr)
            continue
        ep = rd.epoch(fr)
        if ep is not None:
            epochs.append(ep)
    obs_types = {s: _rinex_types(c) for s, c in rd.codes.items()}
    header = ObsHeader(version=0.0, receiver="u-blox (UBX RXM-RAWX)", obs_types=obs_types)
    return UbxLog(path, header, epochs, sfrbx, bool(problems))


def read_ubx(
    path: str | Path,
    problems: Problems,
    signals: Mapping[str, SignalCodes] | None = None,
    systems: Sequence[str] = DEFAULT_SYSTEMS,
) -> tuple[ObsHeader, list[ObsEpoch]]:
    """Read a UBX log's RXM-RAWX epochs (garbled frames are reported with their byte offset)."""
    return parse_ubx(path, problems, signals, systems).observations()


def _rinex_types(c: SignalCodes) -> tuple[str, ...]:
    return tuple(x for x in (c.pseudorange, c.carrier, c.doppler, c.snr) if x is not None)
