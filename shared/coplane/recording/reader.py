"""A fleet recording opened for replay: manifest now, every file lazily and once.

`open_recording` validates fleet.toml (errors raise RecordingError); the RINEX, uwb and truth
files are read on first use and cached, and all their problems go to one `Problems` so a run
can report "N input problems" in one place. Grouping follows the spec: receiver epochs keep
their exact time tags but are grouped by the nearest multiple of `interval_s` (a receiver with
two epochs rounding to one nominal time keeps the first); uwb and truth rows match the nominal
epoch nearest to their tag within 0.1 x interval_s.

Observation files are read by their extension: `.ubx` (u-blox RXM-RAWX, recording/ubx.py),
`.rtcm3` (RTCM 3 MSM4-MSM7, recording/rtcm3.py), anything else RINEX. Navigation files ending
`.rtcm3` give their 1019/1042 ephemerides, `.ubx` their RXM-SFRBX GPS LNAV subframes
(recording/sfrbx.py); a log that is both is parsed once (recording/logs.py). Files are merged in manifest order, the first record of a toe winning. An RTCM 3 obs file's epochs carry no week: it is
taken from the file's own ephemeris messages, else from the recording's navigation data.
"""

from __future__ import annotations

import itertools
import statistics
from collections import Counter
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

from coplane.gtime import GpsTime
from coplane.recording.compressed import file_format
from coplane.recording.csvfiles import read_truth, read_uwb
from coplane.recording.logs import LogCache, log_navigation, log_observations
from coplane.recording.manifest import load_manifest
from coplane.recording.model import Manifest, NavData, ObsEpoch, ObsHeader, TruthPoint, UwbRange
from coplane.recording.problems import Problems, RecordingError
from coplane.recording.rinex_nav import read_nav_files
from coplane.recording.rinex_obs import SignalCodes, read_obs
from coplane.typing import Vec

MATCH_FRACTION = 0.1  # uwb/truth rows match an epoch within this fraction of the interval


@dataclass(frozen=True, slots=True)
class FleetEpoch:
    """Everything observed at one nominal epoch (receivers absent there are simply missing)."""

    time: GpsTime  # nominal: nearest multiple of the manifest interval
    index: int
    vehicles: dict[str, ObsEpoch]  # exact receiver tags stay inside each ObsEpoch
    base: ObsEpoch | None = None
    uwb: tuple[UwbRange, ...] = ()


# A receiver whose median epoch spacing is below this share of the recording's interval logs
# faster than it and is decimated (`Recording._dedupe`); receiver clocks jitter far less.
DECIMATE_BELOW = 0.75


class Recording:
    """Lazy, cached access to one fleet recording."""

    def __init__(self, manifest: Manifest, signals: Mapping[str, SignalCodes] | None = None) -> None:
        self.manifest = manifest
        self.problems = Problems()
        self._signals = signals
        self._nav: NavData | None = None
        self._obs: dict[str, tuple[ObsHeader, list[ObsEpoch]]] = {}
        # a receiver log named as observations and as navigation is parsed once for both
        receivers = [v.obs for v in manifest.vehicles] + ([manifest.base.obs] if manifest.base else [])
        uses = Counter(p for p in [*manifest.nav_files, *receivers] if file_format(p) != "rinex")
        self._logs = LogCache(self.problems, signals, uses)
        self._uwb: list[UwbRange] | None = None
        self._truth: dict[str, list[TruthPoint]] = {}
        self._truth_file: dict[str, Path] = {}  # where a truth given later came from (`use_truth_points`)
        self._truth_at: dict[str, dict[GpsTime, tuple[float, float, float]]] = {}
        self._env_at: dict[str, dict[GpsTime, str]] = {}
        self._fleet: list[FleetEpoch] | None = None
        # observation file -> (epochs skipped, its own spacing s): logs faster than the interval
        self.decimated: dict[Path, tuple[int, float]] = {}

    @property
    def signals(self) -> Mapping[str, SignalCodes] | None:
        """The signal selection the recording was opened with (None: the defaults)."""
        return self._signals

    @property
    def interval_s(self) -> float:
        return self.manifest.interval_s

    def nominal(self, t: GpsTime) -> GpsTime:
        """The nominal epoch time a tag belongs to."""
        return t.round_to(self.manifest.interval_s)

    @property
    def nav(self) -> NavData:
        """The broadcast ephemerides; a recording whose nav files hold none cannot be solved."""
        if self._nav is None:
            nav = NavData()
            for p in self.manifest.nav_files:  # in manifest order: the first file's record wins
                if file_format(p) == "rinex":
                    nav.merge(read_nav_files([p], self.problems))
                else:
                    nav.merge(log_navigation(self._logs.take(p), self.problems))
            if not nav.ephemerides:
                files = ", ".join(str(p) for p in self.manifest.nav_files)
                raise RecordingError(
                    f"no usable broadcast ephemeris in the navigation file(s) {files} "
                    f"({self.problems.total} problem(s) reported): nothing can be positioned"
                )
            self._nav = nav
        return self._nav

    # ---- observations
    def _load_obs(self, key: str, path: Path) -> tuple[ObsHeader, list[ObsEpoch]]:
        if key not in self._obs:
            fmt = file_format(path)
            if fmt == "rinex":
                header, epochs = read_obs(path, self.problems, self._signals)
            else:  # RTCM 3 places its week-less epochs near the navigation data's time
                log = self._logs.take(path)
                header, epochs = log_observations(log, self._reference() if fmt == "rtcm3" else None)
            self._obs[key] = (header, self._dedupe(path, epochs))
        return self._obs[key]

    def _reference(self) -> GpsTime | None:
        """An instant near the recording (`NavData.reference_time`) to place RTCM 3 epochs' weeks;
        None if the navigation data cannot be read (the RTCM file's own ephemerides or the date
        then decide)."""
        try:
            return self.nav.reference_time()
        except RecordingError:
            return None

    def _dedupe(self, path: Path, epochs: list[ObsEpoch]) -> list[ObsEpoch]:
        """One epoch per nominal time. A receiver that logs faster than the recording's interval
        (a 5 Hz log in a 1 s fleet) is decimated: the epoch nearest each nominal time is kept and
        the others are counted in `decimated`, not as input problems, since the interval asked
        for it. Otherwise several epochs on one nominal time are duplicates: the first is kept,
        the others reported."""
        spacing = [b.time - a.time for a, b in itertools.pairwise(epochs)]
        own = statistics.median(spacing) if spacing else None
        if own is not None and 0 < own < DECIMATE_BELOW * self.manifest.interval_s:
            nearest: dict[GpsTime, ObsEpoch] = {}
            for e in epochs:
                t = self.nominal(e.time)
                if t not in nearest or abs(e.time - t) < abs(nearest[t].time - t):
                    nearest[t] = e
            self.decimated[path] = (len(epochs) - len(nearest), own)
            return sorted(nearest.values(), key=lambda e: e.time)
        out: list[ObsEpoch] = []
        seen: dict[GpsTime, GpsTime] = {}
        for e in epochs:
            t = self.nominal(e.time)
            if t in seen:
                self.problems.add(
                    path,
                    None,
                    "duplicate-epoch",
                    f"epoch {e.time} rounds to nominal {t} like epoch {seen[t]}: skipped",
                )
                continue
            seen[t] = e.time
            out.append(e)
        return out

    def decimations(self) -> dict[Path, tuple[int, float]]:
        """`decimated` of every receiver: their observations are read first, as a file's
        decimation is only known once it has been read."""
        for v in self.manifest.vehicles:
            self.vehicle_epochs(v.id)
        self.base_epochs()
        return dict(self.decimated)

    def vehicle_epochs(self, vid: str) -> list[ObsEpoch]:
        return self._load_obs(f"vehicle:{vid}", self.manifest.vehicle(vid).obs)[1]

    def vehicle_header(self, vid: str) -> ObsHeader:
        return self._load_obs(f"vehicle:{vid}", self.manifest.vehicle(vid).obs)[0]

    def base_epochs(self) -> list[ObsEpoch]:
        """The reference station's epochs ([] when the recording has no [base])."""
        if self.manifest.base is None:
            return []
        return self._load_obs("base", self.manifest.base.obs)[1]

    def base_header(self) -> ObsHeader | None:
        if self.manifest.base is None:
            return None
        return self._load_obs("base", self.manifest.base.obs)[0]

    # ---- uwb and truth
    def uwb(self) -> list[UwbRange]:
        """All valid uwb.csv rows ([] without [uwb])."""
        if self._uwb is None:
            spec = self.manifest.uwb
            if spec is None:
                self._uwb = []
            else:
                ids = {v.id for v in self.manifest.vehicles}
                self._uwb = read_uwb(spec.file, self.problems, ids, spec.max_range_m)
        return self._uwb

    def truth(self, vid: str) -> list[TruthPoint]:
        """The vehicle's truth rows ([] when it has none)."""
        if vid not in self._truth:
            path = self.manifest.vehicle(vid).truth
            self._truth[vid] = [] if path is None else read_truth(path, self.problems)
        return self._truth[vid]

    def use_truth(
        self,
        vid: str,
        positions: Mapping[GpsTime, Sequence[float] | Vec],
        environment: Mapping[GpsTime, str] | None = None,
    ) -> None:
        """Replace the vehicle's truth with `positions` (ECEF antenna, keyed by nominal epoch): a
        reference made outside the recording, e.g. RTKLIB's RTK (`coplane eval --truth rtk`).
        `environment`: the label of each epoch, where the reference has one."""
        self.manifest.vehicle(vid)  # KeyError for a vehicle the recording lacks
        env = environment or {}
        rows = {t: (float(p[0]), float(p[1]), float(p[2])) for t, p in sorted(positions.items())}
        self._truth[vid] = [TruthPoint(t, xyz, env.get(t, "")) for t, xyz in rows.items()]
        self._truth_at[vid] = rows
        self._env_at[vid] = {t: env.get(t, "") for t in rows}

    def use_truth_points(self, vid: str, points: list[TruthPoint], source: Path) -> None:
        """Replace the vehicle's truth with `points` read from `source`, another tool's reference
        (`coplane eval --truth ID=FILE`): matched to nominal epochs as the recording's own are."""
        self.manifest.vehicle(vid)  # KeyError for a vehicle the recording lacks
        self._truth[vid] = list(points)
        self._truth_file[vid] = source
        self._truth_at.pop(vid, None)
        self._env_at.pop(vid, None)

    def truth_at(self, vid: str) -> dict[GpsTime, tuple[float, float, float]]:
        """Truth keyed by nominal epoch time: at each epoch the row nearest to it, within 0.1 x
        interval (farther rows are dropped).

        A reference at a higher rate than the recording (an INS at 10-200 Hz) has several rows
        within that reach of one epoch; the nearest is its truth, not the first, which would be
        up to 0.1 s early, metres at road speed. Rows between the epochs of such a reference are
        what it is, not a problem; in a reference at the recording's rate they are reported once.
        """
        if vid not in self._truth_at:
            tol = MATCH_FRACTION * self.manifest.interval_s
            source = self._truth_file.get(vid) or self.manifest.vehicle(vid).truth or ""
            rows = self.truth(vid)
            spacing = [b.time - a.time for a, b in itertools.pairwise(rows)]
            denser = bool(spacing) and statistics.median(spacing) < 0.5 * self.manifest.interval_s
            best: dict[GpsTime, TruthPoint] = {}
            unmatched: list[GpsTime] = []
            for p in rows:
                t = self.nominal(p.time)
                off = abs(p.time - t)
                if off > tol:
                    unmatched.append(p.time)
                    continue
                held = best.get(t)
                nearer = held is None or off < abs(held.time - t)
                if held is not None and (held.time == p.time or not denser):
                    # a second row at one time, or in one epoch's reach of a reference at the
                    # recording's rate, is a fault; a denser reference has several by nature
                    dropped = held if nearer else p
                    self.problems.add(
                        source,
                        None,
                        "duplicate-row",
                        f"truth row at {dropped.time} matches nominal epoch {t} already matched: skipped",
                    )
                if nearer:
                    best[t] = p
            if unmatched and not denser:
                self.problems.add(
                    source,
                    None,
                    "unmatched-row",
                    f"{len(unmatched)} truth row(s) farther than {tol:g} s from any nominal epoch "
                    f"(first at {unmatched[0]}): not used",
                )
            self._truth_at[vid] = {t: best[t].ecef_m for t in sorted(best)}
            self._env_at[vid] = {t: best[t].environment for t in sorted(best)}
        return self._truth_at[vid]

    def environment_at(self, vid: str) -> dict[GpsTime, str]:
        """The truth's environment label at each matched nominal epoch ("" when the truth has none).

        Simulated recordings label every truth row with its road section (open, medium, deep,
        underpass); real recordings may add an `environment` column. Used for per-environment
        accuracy, never by an estimator.
        """
        self.truth_at(vid)  # matches the rows once, for both
        return self._env_at[vid]

    # ---- grouping
    def fleet_epochs(self) -> Iterator[FleetEpoch]:
        """Nominal epochs in time order with every receiver's epoch and the uwb rows matched there."""
        if self._fleet is None:
            self._fleet = self._build_fleet()
        return iter(self._fleet)

    def _build_fleet(self) -> list[FleetEpoch]:
        by_vehicle = {
            v.id: {self.nominal(e.time): e for e in self.vehicle_epochs(v.id)} for v in self.manifest.vehicles
        }
        base = {self.nominal(e.time): e for e in self.base_epochs()}
        times: set[GpsTime] = set(base)
        for m in by_vehicle.values():
            times.update(m)
        ordered = sorted(times)
        uwb = self._match_uwb(set(ordered))
        return [
            FleetEpoch(
                time=t,
                index=i,
                vehicles={vid: m[t] for vid, m in by_vehicle.items() if t in m},
                base=base.get(t),
                uwb=tuple(uwb.get(t, ())),
            )
            for i, t in enumerate(ordered)
        ]

    def _match_uwb(self, times: set[GpsTime]) -> dict[GpsTime, list[UwbRange]]:
        out: dict[GpsTime, list[UwbRange]] = {}
        spec = self.manifest.uwb
        if spec is None:
            return out
        tol = MATCH_FRACTION * self.manifest.interval_s
        pairs: set[tuple[GpsTime, tuple[str, str]]] = set()
        for u in self.uwb():
            t = self.nominal(u.time)
            if abs(u.time - t) > tol or t not in times:
                why = (
                    f"farther than {tol:g} s from nominal {t}"
                    if abs(u.time - t) > tol
                    else "no receiver epoch"
                )
                self.problems.add(
                    spec.file, None, "unmatched-row", f"range {u.a}-{u.b} at {u.time}: {why}: skipped"
                )
                continue
            if (t, u.pair) in pairs:
                self.problems.add(
                    spec.file,
                    None,
                    "duplicate-row",
                    f"pair {u.pair} has two ranges in epoch {t}: kept the first",
                )
                continue
            pairs.add((t, u.pair))
            out.setdefault(t, []).append(u)
        return out


def open_recording(path: str | Path, signals: Mapping[str, SignalCodes] | None = None) -> Recording:
    """Open a fleet recording directory (or its fleet.toml); raises RecordingError if unusable."""
    return Recording(load_manifest(Path(path)), signals)
