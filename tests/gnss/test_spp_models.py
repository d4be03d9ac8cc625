"""SPP's satellite models carried between epochs (`SatModels`) and shared with the node message.

A receiver's next fit starts from its last fit's models instead of evaluating them at the
previous fix; the fit still ends with the models evaluated where it converged, so the position is
the one a cold start finds. The Doppler rows and the node message take the view SPP ended with.
"""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from coplane.gnss import spp as spp_module
from coplane.gnss.epoch_solver import ReceiverMemory, solve_epoch, solve_next
from coplane.gnss.measurements import prepare_epoch
from coplane.gnss.sat_models import SatModels
from coplane.gnss.spp import solve_spp
from coplane.recording.reader import open_recording

BUNDLED = Path(__file__).resolve().parents[2] / "shared/coplane/data/recordings/default"


@pytest.fixture(scope="module")
def drive():  # type: ignore[no-untyped-def]
    rec = open_recording(BUNDLED)
    vid = rec.manifest.vehicles[0].id
    return rec.nav, list(rec.vehicle_epochs(vid))[:60]


def _count_model_evaluations(monkeypatch: pytest.MonkeyPatch) -> list[int]:
    calls = [0]
    original = spp_module.broadcast_delays

    def counting(*args, **kwargs):  # type: ignore[no-untyped-def]
        calls[0] += 1
        return original(*args, **kwargs)

    monkeypatch.setattr(spp_module, "broadcast_delays", counting)
    return calls


def test_carried_models_give_the_cold_start_fix_with_fewer_evaluations(drive, monkeypatch) -> None:  # type: ignore[no-untyped-def]
    nav, epochs = drive
    memory = ReceiverMemory()
    calls = _count_model_evaluations(monkeypatch)
    warm_calls = cold_calls = 0
    for ep in epochs:
        fix, models = memory.fix, memory.models
        before = calls[0]
        warm = solve_next(ep, nav, memory)
        warm_calls += calls[0] - before
        if fix is None:
            continue
        before = calls[0]
        cold = solve_epoch(ep, nav, initial_position=fix)  # the same start, no models
        cold_calls += calls[0] - before
        assert warm.spp.ok and cold.spp.ok
        assert models is not None and models.time < ep.time
        assert np.linalg.norm(warm.spp.position - cold.spp.position) < 1e-3
        assert warm.spp.sigmas_m == pytest.approx(cold.spp.sigmas_m, rel=1e-5)
        # the models are evaluated within a decimetre of the fix, and the Doppler uses that point
        assert np.linalg.norm(warm.spp.model_position - warm.spp.position) <= 0.1
    assert warm_calls < 0.75 * cold_calls, (warm_calls, cold_calls)


def test_models_start_a_fit_only_when_they_cover_it(drive) -> None:  # type: ignore[no-untyped-def]
    nav, epochs = drive
    first = solve_spp(prepare_epoch(epochs[0], nav), nav)
    assert first.ok and first.models is not None
    models = first.models
    nxt = prepare_epoch(epochs[1], nav)
    sats = list(nxt.sats)
    tgd = np.zeros(len(sats))
    assert models.atmosphere(nxt.time, sats, tgd, differential=False) is not None
    assert models.atmosphere(nxt.time, sats, tgd, differential=True) is None  # DGNSS models differ
    assert models.atmosphere(models.time, sats, tgd, differential=False) is None  # not older
    assert models.atmosphere(models.time + 31.0, sats, tgd, differential=False) is None  # too old
    # a satellite out of sight for a while is kept, up to the age limit
    gone = sats[0].sat
    later = SatModels(
        models.time + 5.0, False, {k: (*v[:3], v[3] + 5.0) for k, v in models.by_sat.items() if k != gone}
    )
    assert gone in later.merged(models).by_sat
    assert gone not in replace(later, time=models.time + 31.0).merged(models).by_sat
    assert later.merged(models).by_sat[sats[1].sat] == later.by_sat[sats[1].sat]  # the newer wins
    missing = SatModels(models.time, False, {k: v for k, v in models.by_sat.items() if k != sats[0].sat})
    assert missing.atmosphere(nxt.time, sats, tgd, differential=False) is None
    # a stale set still gives the cold start's fix: it only starts the iterations
    stale = replace(models, by_sat={k: (0.5, 0.0, 3.0, v[3]) for k, v in models.by_sat.items()})
    a = solve_spp(nxt, nav, initial_position=first.position, models=stale)
    b = solve_spp(nxt, nav, initial_position=first.position)
    assert a.ok and b.ok and np.linalg.norm(a.position - b.position) < 1e-3


def test_the_step_bound_ends_iterations_within_the_threshold(drive, monkeypatch) -> None:  # type: ignore[no-untyped-def]
    """A step short enough that its linearisation error is below `convergence_m` ends the fit
    (`spp._converged`): the fix is within that threshold of iterating on until the step itself
    is, and takes fewer iterations."""
    nav, epochs = drive
    bounded, plain = ReceiverMemory(), ReceiverMemory()
    its = {"bounded": 0, "plain": 0}
    for ep in epochs:
        a = solve_next(ep, nav, bounded)
        with monkeypatch.context() as m:
            m.setattr(spp_module, "_GN_GAIN", math.inf)  # only a step under the threshold converges
            b = solve_next(ep, nav, plain)
        assert a.spp.ok and b.spp.ok
        assert np.linalg.norm(a.spp.position - b.spp.position) < 1e-4
        its["bounded"] += a.spp.iterations
        its["plain"] += b.spp.iterations
    assert its["bounded"] < 0.8 * its["plain"], its
