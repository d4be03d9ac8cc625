"""The receivers' GNSS front ends of a recording, computed once for several method runs.

A vehicle's front end (SPP, Doppler: `VehicleStep.front_end`) uses its own receiver's data only,
never the fleet's solution, so every method that runs it with the same solver options and the same
base corrections computes the same bits. `coplane eval` and the benchmark run five to ten methods
on each recording, and the front end is about a third of a method's run: a `FrontEndMemo` passed
to each run computes it once. Kept per `Recording` object (weakly: it goes with the recording).
The base station's corrections, which every run's front ends and node messages ask for epoch by
epoch, are kept the same way (`FrontEndMemo.base`).

For runs in one process (`jobs=1`): there it takes a quarter to two fifths off a method's run on
the bundled recording. With vehicle workers the front ends already run beside the fusion step, and
a memo measured slower there (docs/performance.md, "coplane eval on the bundled recording").

The results are shared between runs, not copied: nothing downstream changes them (their arrays
are read-only, as the sky-view caches already require; `geometry.sky_view`).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any
from weakref import WeakKeyDictionary

from coplane.gnss.dgnss import DgnssCorrections
from coplane.gnss.epoch_solver import EpochResult
from coplane.gtime import GpsTime
from coplane.recording.reader import Recording
from coplane.replay import BaseCorrections
from coplane.steps import VehicleStep

# A remembered epoch is about 17 kB (its prepared satellites, SPP and Doppler solutions; tracemalloc
# on one simulated dense-urban receiver, 2026-12-01), so the default bound, 20 000 vehicle-epochs
# (a 4-vehicle recording of 80 min at 1 Hz), is ~350 MB.
DEFAULT_MAX_EPOCHS = 20_000

Schedule = list[tuple[GpsTime, dict[str, Any]]]
Fronts = dict[tuple[int, str], EpochResult]


class FrontEndMemo:
    """Front-end results per recording, vehicle and front-end setup, up to `max_epochs` in all.

    Past the bound nothing more is remembered (runs stay correct, only no faster), so a long
    recording cannot fill the memory; a recording that is gone frees its share.
    """

    def __init__(self, max_epochs: int = DEFAULT_MAX_EPOCHS) -> None:
        self.max_epochs = max_epochs
        self._kept: WeakKeyDictionary[Recording, dict[tuple[str, bool, str], dict[GpsTime, EpochResult]]]
        self._kept = WeakKeyDictionary()
        self._bases: WeakKeyDictionary[Recording, dict[bool, BaseCorrections]] = WeakKeyDictionary()

    @property
    def n_epochs(self) -> int:
        """Vehicle-epochs remembered for the recordings still alive."""
        return sum(len(r) for per_rec in list(self._kept.values()) for r in per_rec.values())

    def base(self, rec: Recording, dgnss: bool) -> BaseCorrections:
        """The base station's corrections of `rec`, one object for every run (each epoch computed
        once, `BaseCorrections.remembering`): the vehicles' front ends and the node messages of
        every method need them. At most `max_epochs` epochs per recording and mode are kept
        (about 5 kB each: 100 MB at the default bound)."""
        per_rec = self._bases.setdefault(rec, {})
        if dgnss not in per_rec:
            per_rec[dgnss] = BaseCorrections.of(rec, dgnss).remembering(self.max_epochs)
        return per_rec[dgnss]

    def fronts(
        self,
        rec: Recording,
        steps: Mapping[str, VehicleStep],
        schedule: Schedule,
        dgnss: bool,
        corrections: Callable[[int], DgnssCorrections | None],
    ) -> Fronts:
        """Every front end of `steps`' vehicles over `schedule`, keyed (epoch index, vehicle): the
        remembered ones, the others computed now with `steps` (in order, so that each receiver
        starts from its previous fix) and remembered while the bound allows. `corrections(k)`:
        the base corrections of epoch k (with `dgnss`)."""
        kept = self._kept.setdefault(rec, {})
        keys = {vid: (vid, dgnss, repr(s.config.solver)) for vid, s in steps.items()}
        todo = {vid for vid, key in keys.items() if key not in kept}
        new: dict[str, dict[GpsTime, EpochResult]] = {vid: {} for vid in todo}
        out: Fronts = {}
        for k, (t, live) in enumerate(schedule):
            corr = corrections(k) if todo & live.keys() else None
            for vid, ep in sorted(live.items()):
                if vid in todo:
                    new[vid][t] = steps[vid].front_end(t, ep, corr)
                    out[(k, vid)] = new[vid][t]
                elif vid in keys:
                    out[(k, vid)] = kept[keys[vid]][t]
        for vid, results in new.items():
            if self.n_epochs + len(results) <= self.max_epochs:
                kept[keys[vid]] = results
        return out
