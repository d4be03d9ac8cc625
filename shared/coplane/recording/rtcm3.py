"""RTCM 3 observation files: MSM4 to MSM7 (1074-1077 GPS, 1124-1127 BeiDou) in and out (MSM7 by
default), broadcast ephemerides 1019 (GPS) and 1042 (BeiDou) in and out, through pyrtcm.

Reading gives the RINEX reader's model (coplane.recording.model): "G05" / "C12", the selected
signal per system (GPS L1 C/A = MSM signal 2 "1C", BeiDou B1I = "2I"), metres, Hz with the RINEX
sign, dB-Hz, cycles; the same validity rules as RINEX.

MSM7 resolutions (RTCM 10403.3; c = 299 792 458 m/s, 1 ms of light = 299 792.458 m):
* pseudorange: rough range DF397 (1 ms) + DF398 (2^-10 ms = 292.8 m) + fine DF405 (2^-29 ms =
  0.558 mm): the value is rounded to 0.56 mm, an error of at most 0.28 mm;
* phase range: DF406 2^-31 ms = 0.140 mm (valid within +-2^-8 ms = 1171 m of the rough range);
* phase-range rate: DF399 1 m/s + DF404 0.0001 m/s, so Doppler = -rate/lambda is kept to
  0.05 mm/s, 2.6e-4 Hz on L1 / B1I;
* C/N0: DF408 2^-4 = 0.0625 dB-Hz (MSM4: DF403 1 dB-Hz, and MSM4 has no Doppler);
* MSM5 is MSM4's resolution with MSM7's phase-range rates (Doppler), MSM6 MSM7's resolution
  without them: receivers and casters choose by bandwidth, so a base station's stream may be any;
* epoch time: DF004 (GPS) / DF427 (BDT) whole milliseconds of the week, no week number.
Ephemeris LSBs are those of the ICDs, which RTCM copies (pyrtcm's RTCM_DATA_FIELDS carries them:
e.g. 1019 sqrt(A) 2^-19 m^0.5, M0 2^-31 semicircles, toe 16 s; 1042 a0 2^-33 s, toe 8 s); real
broadcast values sit on those grids, so 1019/1042 reproduce a RINEX navigation file's values to
its 12 printed digits. The accuracy (URA index) and fit interval are indices: sva is read back as
the upper bound of its URA bin (RTKLIB's convention; the same ephemeris variance), fit 0 -> 4 h.

Time (docs/recording-format.md, "UBX and RTCM 3 obs files"):
* MSM epochs carry whole milliseconds. A receiver tag with a sub-millisecond part d (a
  free-running clock: the simulator's tags are 3.97 ms late and drifting) is moved to the nearest
  millisecond and each measurement is carried there along its own rate: P' = P + d*lambda*D,
  L' = L + d*D (the RINEX Doppler D is -dP/dt / lambda). The error is the acceleration term,
  a*d^2/2 < 1e-6 m for d <= 0.5 ms; the receiver clock keeps its bias and drift, so estimators
  that model the clock see the same clock. The receiver itself moves by v*d (7 mm at 15 m/s and
  d = 0.5 ms), which is the one real difference from the RINEX epoch. Relabelling the clock
  instead (P' = P - c*d) is exact for a snapshot solution but makes the clock jump against its
  Doppler-measured drift, which coplane's filters reject (1 km errors); RTKLIB's encoder rounds
  the tag and leaves P alone (d * range rate: up to 0.4 m). Without a Doppler, D = 0 is used.
* BeiDou MSM and 1042 times are BDT (GPST - 14 s, BDT week = GPS week - 1356), converted here.
* MSM has no week: each epoch takes the week that puts it nearest the previous epoch (the first
  one: nearest the reference instant). The reference is the caller's (`reference`: the
  recording's navigation, `Recording._reference`), else the median toe of the 1042s (13-bit BDT
  week: unambiguous until 2163), else of the 1019s resolved against today's date, else today's
  date; the median, so that a stray ephemeris of another week does not move the log. 1019's
  10-bit week is resolved to the 1024-week cycle nearest the reference (RTKLIB's rule in real
  time), so a log is read right for +-512 weeks (9.8 years).

MSM reading and writing stay one file: each field's scaling is written once and used both ways,
and the round-trip tests check the pair. Ephemeris messages live in rtcm3_ephemeris.py, the URA
table and week rules shared with UBX in broadcast.py.
"""

from __future__ import annotations

import math
import statistics
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from pyrtcm import RTCMReader
from pyrtcm.rtcmtables import BEIDOU_SIG_MAP, GPS_SIG_MAP

from coplane.gtime import GpsTime, bdt_to_gpst, gpst_to_bdt
from coplane.recording.broadcast import nearest_week, resolve_week, today
from coplane.recording.compressed import read_log_bytes
from coplane.recording.frames import Frame, Skipped, rtcm_frames
from coplane.recording.lock_time import LockTimer
from coplane.recording.model import NavData, ObsEpoch, ObsHeader, SatObservation
from coplane.recording.problems import Problems
from coplane.recording.rinex_obs import (
    DEFAULT_SIGNALS,
    DEFAULT_SYSTEMS,
    PSEUDORANGE_MAX_M,
    PSEUDORANGE_MIN_M,
    SNR_MAX_DBHZ,
    SNR_MIN_DBHZ,
    SignalCodes,
)
from coplane.recording.rtcm3_ephemeris import EPHEMERIS, decode_ephemeris, ephemeris_frame, field_lsb
from coplane.recording.rtcm_encode import FieldRangeError, build_frame

C_LIGHT = 299_792_458.0
LIGHT_MS = C_LIGHT * 1e-3  # metres per millisecond of light travel
FREQ_HZ = {"G": 1575.42e6, "C": 1561.098e6}  # L1 C/A, B1I: the only carriers written
MSM_IDS = {n: {"G": f"107{n}", "C": f"112{n}"} for n in (4, 5, 6, 7)}  # MSM4..MSM7 per system
MSM7 = MSM_IDS[7]


def msm_extended(level: int) -> bool:
    """Whether an MSM level carries the extended resolution (MSM6, MSM7: DF405-DF408)."""
    return level in (6, 7)


def msm_rates(level: int) -> bool:
    """Whether an MSM level carries the phase-range rates, the Doppler (MSM5, MSM7: DF399, DF404)."""
    return level in (5, 7)


_SIG_MAPS = {"G": GPS_SIG_MAP, "C": BEIDOU_SIG_MAP}
_SYSTEM_OF = {"107": "G", "112": "C"}
_P2_10, _P2_29, _P2_24, _P2_31 = 2.0**-10, 2.0**-29, 2.0**-24, 2.0**-31
PSEUDORANGE_LSB_M = _P2_29 * LIGHT_MS  # 0.558 mm
RATE_LSB_MPS = 1e-4
CNR_LSB_DBHZ = 2.0**-4
_WEEK_MS = 604_800_000
_BDT_LAG_MS = 14_000  # GPST - BDT


def msm_signal_id(sys: str, code: str) -> int:
    """MSM signal id (1..32) of a RINEX observation code, from pyrtcm's signal tables."""
    band = code[1:]
    if sys == "C" and band == "1I":  # RINEX 3.02 name of B1I
        band = "2I"
    for sid, (_, rinex) in _SIG_MAPS[sys].items():
        if rinex == band:
            return sid
    raise ValueError(f"no MSM signal for {sys} {code}")


# --------------------------------------------------------------------------------------------
# MSM writing


_LOCK_STEPS = 21  # DF407 blocks of 32 indices above 64, each doubling the step


def lock_indicator(ms: int) -> int:
    """DF407 extended lock-time indicator for a lock time in milliseconds (RTCM table 3.5-74)."""
    if ms < 64:
        return max(0, ms)
    k = min(_LOCK_STEPS - 1, int(math.log2(ms / 64)))
    start = 64 << k
    return min(704, 64 + 32 * k + (ms - start) // (2 << k))


def msm_tag(t: GpsTime) -> tuple[GpsTime, float]:
    """(whole-millisecond tag, d = t - tag in seconds) for an MSM epoch."""
    ms = round(t.tow * 1000.0)
    tag = GpsTime(t.week, ms / 1000.0)
    return tag, t - tag


def msm_frames(
    ep: ObsEpoch,
    signals: Mapping[str, SignalCodes],
    station: int = 0,
    msm: int = 7,
    lock: LockTimer | None = None,
) -> list[bytes]:
    """One epoch as MSM7 (or MSM4, 5, 6) frames: GPS then BeiDou, the multiple-message bit set on
    all but the last."""
    if msm not in MSM_IDS:
        raise ValueError(f"MSM{msm}: coplane writes MSM4 to MSM7")
    lock = lock or LockTimer()
    tag, shift = msm_tag(ep.time)
    by_sys: dict[str, list[SatObservation]] = {}
    for s in ep.sats:
        if s.sat[0] not in MSM7 or s.sat[0] not in signals:
            raise ValueError(f"satellite {s.sat}: system {s.sat[0]} cannot be written as MSM")
        by_sys.setdefault(s.sat[0], []).append(s)
    # an epoch without satellites (an underpass) is still an epoch: an empty GPS message says so
    systems = [x for x in ("G", "C") if x in by_sys] or ["G"]
    out: list[bytes] = []
    for n, sys in enumerate(systems):
        sats = sorted(by_sys.get(sys, []), key=lambda s: int(s.sat[1:]))
        v = _msm_values(sys, sats, tag, shift, signals[sys], msm, lock)
        v |= {"DF003": station, "DF393": 1 if n < len(systems) - 1 else 0}
        out.append(build_frame(MSM_IDS[msm][sys], v))
    return out


def _msm_values(
    sys: str,
    sats: list[SatObservation],
    tag: GpsTime,
    shift: float,
    sig: SignalCodes,
    msm: int,
    locks: LockTimer,
) -> dict[str, int]:
    lam = C_LIGHT / FREQ_HZ[sys]
    tow_ms = round(tag.tow * 1000.0) if sys == "G" else round(gpst_to_bdt(tag)[1] * 1000.0)
    sid = msm_signal_id(sys, sig.pseudorange)
    v: dict[str, int] = {
        "DF004" if sys == "G" else "DF427": tow_ms,
        "DF394": sum(1 << (64 - int(s.sat[1:])) for s in sats),
        "DF395": (1 << (32 - sid)) if sats else 0,
        "DF396": (1 << len(sats)) - 1,
    }
    for i, s in enumerate(sats, start=1):
        k = f"_{i:02d}"
        dop = s.doppler_hz if math.isfinite(s.doppler_hz) else 0.0
        pr_ms = (s.pseudorange_m + shift * lam * dop) / LIGHT_MS
        r10 = round(pr_ms * 1024.0)
        v["DF397" + k], v["DF398" + k] = divmod(r10, 1024)
        rough = r10 * _P2_10
        has_cp = math.isfinite(s.carrier_cycles)
        cp_ms = (s.carrier_cycles + shift * dop) * lam / LIGHT_MS if has_cp else math.nan
        cn0 = s.cn0_dbhz
        lock = locks.ms(s.sat, tag, has_cp)
        if msm_extended(msm):
            v["DF405" + k] = round((pr_ms - rough) / _P2_29)
            fine_cp = round((cp_ms - rough) / _P2_31) if has_cp else -(1 << 23)
            v["DF406" + k] = fine_cp if abs(fine_cp) < (1 << 23) else -(1 << 23)
            v["DF407" + k] = lock_indicator(lock)
            v["DF408" + k] = 0 if not math.isfinite(cn0) else max(1, min(1023, round(cn0 / CNR_LSB_DBHZ)))
        else:
            v["DF400" + k] = round((pr_ms - rough) / _P2_24)
            fine_cp = round((cp_ms - rough) / _P2_29) if has_cp else -(1 << 21)
            v["DF401" + k] = fine_cp if abs(fine_cp) < (1 << 21) else -(1 << 21)
            v["DF402" + k] = min(15, lock_indicator(lock) // 64)  # coarse: MSM4 lock is 4 bits
            v["DF403" + k] = 0 if not math.isfinite(cn0) else max(1, min(63, round(cn0)))
        if msm_rates(msm):
            if math.isfinite(s.doppler_hz):
                rate = -s.doppler_hz * lam
                v["DF399" + k] = round(rate)
                v["DF404" + k] = round((rate - round(rate)) / RATE_LSB_MPS)
            else:
                v["DF399" + k], v["DF404" + k] = -(1 << 13), -(1 << 14)
    return v


@dataclass
class WriteReport:
    epochs: int = 0
    ephemerides: int = 0
    skipped: list[str] = field(default_factory=list)  # what did not fit its message, and why


def write_rtcm3(
    path: str | Path,
    epochs: Iterable[ObsEpoch],
    nav: NavData | None = None,
    signals: Mapping[str, SignalCodes] | None = None,
    station: int = 0,
    msm: int = 7,
) -> WriteReport:
    """Write 1019/1042 for every ephemeris of `nav` (first), then one MSM set per epoch."""
    sig = dict(DEFAULT_SIGNALS if signals is None else signals)
    rep = WriteReport()
    locks = LockTimer()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("wb") as f:
        for ephs in nav.ephemerides.values() if nav else ():
            for e in ephs:
                if e.system not in EPHEMERIS:
                    continue
                try:
                    f.write(ephemeris_frame(e))
                    rep.ephemerides += 1
                except FieldRangeError as exc:
                    rep.skipped.append(f"{e.sat} toe {e.toe}: {exc}")
        for ep in epochs:
            try:
                frames = msm_frames(ep, sig, station, msm, locks)
            except FieldRangeError as exc:
                rep.skipped.append(f"epoch {ep.time}: {exc}")
                continue
            for fr in frames:
                f.write(fr)
            rep.epochs += 1
    return rep


# --------------------------------------------------------------------------------------------
# Reading


def _raw(msg: Any, name: str, df: str) -> int:
    """A parsed field back in LSB units (pyrtcm scales it)."""
    return round(float(getattr(msg, name)) / field_lsb(df))


@dataclass
class Msm:
    """One MSM message of an epoch: where it was, its system and GPST time tag."""

    offset: int
    sys: str
    tow_ms: int  # GPST milliseconds of week
    msg: Any


class RtcmReader:
    """RTCM 3 frames -> MSM observation sets and ephemeris messages, one frame at a time (the
    file reader and live streams / NTRIP)."""

    def __init__(
        self, path: str | Path, problems: Problems, signals: Mapping[str, SignalCodes], systems: Sequence[str]
    ) -> None:
        self.path = path
        self.problems = problems
        self.codes = {s: signals[s] for s in systems if s in MSM7 and s in signals}
        self.sig_id = {s: msm_signal_id(s, c.pseudorange) for s, c in self.codes.items()}

    def _p(self, offset: int, kind: str, reason: str) -> None:
        self.problems.add(self.path, None, kind, reason, offset=offset)

    def take(self, item: Frame | Skipped) -> Msm | tuple[int, Any] | None:
        """An MSM of a wanted system, an (offset, message) of 1019/1042/1005/1006, or None (other
        messages, and bad ones, which are counted)."""
        if not isinstance(item, Frame):
            if not item.ascii:
                self._p(item.offset, "garbled-frame", f"{item.length} byte(s) skipped: {item.reason}")
            return None
        try:
            msg = RTCMReader.parse(item.raw)
            ident = msg.identity
        except Exception as exc:  # pyrtcm raises its own types and IndexError/ValueError
            self._p(item.offset, "malformed-frame", f"RTCM frame does not decode: {exc}")
            return None
        sys = _SYSTEM_OF.get(ident[:3])
        if ident in ("1019", "1042", "1005", "1006"):
            return (item.offset, msg)
        if sys in self.codes and ident[3:] in ("4", "5", "6", "7"):
            ms = int(msg.DF004) if sys == "G" else int(msg.DF427) + _BDT_LAG_MS
            if not 0 <= int(msg.DF004 if sys == "G" else msg.DF427) < _WEEK_MS:
                self._p(item.offset, "malformed-epoch", f"MSM {ident} epoch time {ms} ms: skipped")
                return None
            return Msm(item.offset, sys, ms % _WEEK_MS, msg)
        return None

    def parse(self, data: bytes) -> tuple[list[Msm], list[tuple[int, Any]]]:
        msms: list[Msm] = []
        ephs: list[tuple[int, Any]] = []
        for item in rtcm_frames(data):
            got = self.take(item)
            if isinstance(got, Msm):
                msms.append(got)
            elif got is not None and got[1].identity in ("1019", "1042"):
                ephs.append(got)
        return msms, ephs

    def epochs(self, msms: list[Msm], reference: GpsTime) -> list[ObsEpoch]:
        out: list[ObsEpoch] = []
        cur: list[Msm] = []
        ref = reference
        last: GpsTime | None = None
        for m in [*msms, None]:
            if m is not None and cur and m.tow_ms == cur[0].tow_ms:
                cur.append(m)
                continue
            if cur:
                t = nearest_week(cur[0].tow_ms / 1000.0, ref)
                if last is not None and t <= last:
                    self._p(cur[0].offset, "non-monotonic-time", f"epoch {t} is not after {last}: skipped")
                else:
                    out.append(self.epoch(t, cur))
                    ref = last = t
            cur = [m] if m is not None else []
        return out

    def epoch(self, t: GpsTime, msgs: list[Msm]) -> ObsEpoch:
        """One epoch from its MSMs (all of one time tag)."""
        sats: list[SatObservation] = []
        seen: set[str] = set()
        for m in msgs:
            for s in self._msm_sats(m):
                if s.sat in seen:
                    self._p(m.offset, "duplicate-satellite", f"{s.sat} twice in epoch {t}: kept the first")
                    continue
                seen.add(s.sat)
                sats.append(s)
        return ObsEpoch(t, tuple(sats))

    def _msm_sats(self, m: Msm) -> list[SatObservation]:
        msg, sys = m.msg, m.sys
        level = int(msg.identity[3])
        extended, rates = msm_extended(level), msm_rates(level)
        code = self.codes[sys]
        lam = C_LIGHT / FREQ_HZ[sys]
        index = {int(getattr(msg, f"PRN_{i:02d}")): i for i in range(1, msg.NSat + 1)}
        out: list[SatObservation] = []
        for c in range(1, msg.NCell + 1):
            k = f"_{c:02d}"
            prn = int(getattr(msg, "CELLPRN" + k))
            if msm_signal_id(sys, "C" + str(getattr(msg, "CELLSIG" + k))) != self.sig_id[sys]:
                continue
            i = index[prn]
            sk = f"_{i:02d}"
            n_ms = int(getattr(msg, "DF397" + sk))
            if n_ms == 255:
                continue  # rough range invalid
            rough = n_ms + _raw(msg, "DF398" + sk, "DF398") * _P2_10
            if extended:
                fine_pr, fine_cp = _raw(msg, "DF405" + k, "DF405"), _raw(msg, "DF406" + k, "DF406")
                pr_ok, cp_ok = fine_pr != -(1 << 19), fine_cp != -(1 << 23)
                pr_ms, cp_ms = rough + fine_pr * _P2_29, rough + fine_cp * _P2_31
                cn0 = _raw(msg, "DF408" + k, "DF408") * CNR_LSB_DBHZ
            else:
                fine_pr, fine_cp = _raw(msg, "DF400" + k, "DF400"), _raw(msg, "DF401" + k, "DF401")
                pr_ok, cp_ok = fine_pr != -(1 << 14), fine_cp != -(1 << 21)
                pr_ms, cp_ms = rough + fine_pr * _P2_24, rough + fine_cp * _P2_29
                cn0 = float(_raw(msg, "DF403" + k, "DF403"))
            sat = f"{sys}{prn:02d}"
            pr = pr_ms * LIGHT_MS
            if not pr_ok:
                continue
            if not PSEUDORANGE_MIN_M <= pr <= PSEUDORANGE_MAX_M:
                self._p(m.offset, "absurd-value", f"{sat}: pseudorange {pr} m outside 1.5e7..5e7 m")
                continue
            dop = math.nan
            if rates and code.doppler is not None:
                rough_rate = int(getattr(msg, "DF399" + sk))
                fine_rate = _raw(msg, "DF404" + k, "DF404")
                if rough_rate != -(1 << 13) and fine_rate != -(1 << 14):
                    dop = -(rough_rate + fine_rate * RATE_LSB_MPS) / lam
            snr = math.nan
            if code.snr is not None and cn0 != 0.0:
                if SNR_MIN_DBHZ <= cn0 <= SNR_MAX_DBHZ:
                    snr = cn0
                else:
                    self._p(m.offset, "absurd-value", f"{sat}: C/N0 {cn0} dB-Hz outside 0..70")
            cp = cp_ms * LIGHT_MS / lam if (cp_ok and code.carrier is not None) else math.nan
            out.append(SatObservation(sat, pr, dop, snr, cp))
        return out

    def reference(self, ephs: list[tuple[int, Any]], given: GpsTime | None) -> GpsTime:
        """`given`, else the median toe of the log's 1042s, else of its 1019s (their weeks
        resolved against today), else today. The median: one stray ephemeris of another week
        must not move every epoch of the log by weeks (`Recording._reference`)."""
        if given is not None:
            return given
        now = today()
        bds = [t for _, m in ephs if m.identity == "1042" and (t := _toe(m, now)) is not None]
        if bds:
            return statistics.median_low(bds)
        gps = [t for _, m in ephs if (t := _toe(m, now)) is not None]
        return statistics.median_low(gps) if gps else now

    def nav(self, ephs: list[tuple[int, Any]], reference: GpsTime) -> NavData:
        nav = NavData()
        for offset, msg in ephs:
            try:
                nav.add(decode_ephemeris(msg, reference))
            except (ValueError, AttributeError) as exc:
                self._p(offset, "malformed-record", f"ephemeris {msg.identity} does not decode: {exc}")
        return nav


def _toe(msg: Any, now: GpsTime) -> GpsTime | None:
    """A 1042's or a 1019's toe (a 1019's 10-bit week resolved near `now`); None for a message
    whose fields do not make one (it is named when the ephemerides are decoded, `nav`)."""
    try:
        if msg.identity == "1042":
            return bdt_to_gpst(int(msg.DF489), float(msg.DF505))
        return GpsTime(resolve_week(int(msg.DF076), 10, now.week), float(msg.DF093))
    except (AttributeError, TypeError, ValueError, OverflowError):
        return None


def _load(path: Path) -> bytes:
    return read_log_bytes(path, "RTCM 3")  # .rtcm3, or archived (.rtcm3.gz)


@dataclass
class Rtcm3Log:
    """One pass over an RTCM 3 log: its MSMs and its ephemerides, decoded on demand. A log often
    carries both, and a recording takes it as observations and as a navigation source
    (`coplane.recording.logs`): read once, its damage is counted once. The epochs' weeks need a
    reference time the whole recording's navigation gives, hence `reference` at the call."""

    reader: RtcmReader
    msms: list[Msm]
    ephs: list[tuple[int, Any]]

    def observations(self, reference: GpsTime | None = None) -> tuple[ObsHeader, list[ObsEpoch]]:
        """MSM4-MSM7 epochs, their weeks placed near `reference` (None: the log's own ephemerides, else today)."""
        rd = self.reader
        epochs = rd.epochs(self.msms, rd.reference(self.ephs, reference))
        obs_types = {
            s: tuple(x for x in (c.pseudorange, c.carrier, c.doppler, c.snr) if x)
            for s, c in rd.codes.items()
        }
        return ObsHeader(version=0.0, receiver="RTCM 3 MSM", obs_types=obs_types), epochs

    def navigation(self, reference: GpsTime | None = None) -> NavData:
        """The 1019/1042 ephemerides."""
        return self.reader.nav(self.ephs, self.reader.reference(self.ephs, reference))


def parse_rtcm3(
    path: str | Path,
    problems: Problems,
    signals: Mapping[str, SignalCodes] | None = None,
    systems: Sequence[str] = DEFAULT_SYSTEMS,
) -> Rtcm3Log:
    """An RTCM 3 log read once (garbled frames reported with their byte offset)."""
    path = Path(path)
    rd = RtcmReader(path, problems, dict(DEFAULT_SIGNALS if signals is None else signals), systems)
    msms, ephs = rd.parse(_load(path))
    return Rtcm3Log(rd, msms, ephs)


def read_rtcm3(
    path: str | Path,
    problems: Problems,
    signals: Mapping[str, SignalCodes] | None = None,
    systems: Sequence[str] = DEFAULT_SYSTEMS,
    reference: GpsTime | None = None,
) -> tuple[ObsHeader, list[ObsEpoch]]:
    """MSM4-MSM7 epochs of an RTCM 3 file (garbled frames reported with their byte offset)."""
    return parse_rtcm3(path, problems, signals, systems).observations(reference)


def read_rtcm3_nav(path: str | Path, problems: Problems, reference: GpsTime | None = None) -> NavData:
    """The 1019/1042 ephemerides of an RTCM 3 file."""
    return parse_rtcm3(path, problems).navigation(reference)
