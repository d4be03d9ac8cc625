"""The two opt-ins of docs/fgo.md "A deep-canyon start" (off by default): pseudoranges without
redundancy loosened (`unverified_sigma_scale`), and a Doppler outage extrapolating the window's
newest Doppler velocity (`motion_last_doppler`)."""

from __future__ import annotations

import dataclasses

import gtsam
import numpy as np
from support.fgo_synthetic import SyntheticFleet, make_fleet

from coplane.estimation.contract import EpochInput
from coplane.fgo.config import FgoConfig
from coplane.fgo.engine import FusionEstimator
from coplane.geo import up_vector
from coplane.methods import get_method


def _robust() -> FgoConfig:
    cfg = get_method("non-cp").fgo
    assert cfg is not None and cfg.unverified_sigma_scale == 1.0 and not cfg.motion_last_doppler
    return cfg


def _pseudorange_sigmas(est: FusionEstimator, vid: str) -> list[float]:
    """The sigmas of the pseudorange factors of the vehicle's newest state."""
    out = []
    graph = est._state.window.by_vehicle[vid][-1].graph()
    for i in range(graph.size()):
        f = graph.at(i)
        if isinstance(f, gtsam.PseudorangeFactor | gtsam.DifferentialPseudorangeFactor):
            nm = f.noiseModel()
            base = nm.noise() if isinstance(nm, gtsam.noiseModel.Robust) else nm
            out.append(float(base.sigmas()[0]))
    return out


def test_an_epoch_no_test_can_check_gets_looser_pseudoranges() -> None:
    """4 GPS satellites determine position and clock with nothing left over: scaled; a full epoch
    (8 GPS + 6 BeiDou) is not."""
    fleet = make_fleet(1, 8, seed=4, sat_limit={("v01", 5): 4})
    sigmas: dict[float, dict[int, list[float]]] = {}
    for scale in (1.0, 3.0):
        est = FusionEstimator(dataclasses.replace(_robust(), unverified_sigma_scale=scale))
        sigmas[scale] = {}
        for k, epoch in enumerate(fleet.epochs[:6]):
            est.step(epoch)
            sigmas[scale][k] = _pseudorange_sigmas(est, "v01")
    assert len(sigmas[1.0][5]) == 4 and len(sigmas[1.0][4]) == 14
    np.testing.assert_allclose(sigmas[3.0][5], 3.0 * np.array(sigmas[1.0][5]))
    assert sigmas[3.0][4] == sigmas[1.0][4]


def _outage_from(fleet: SyntheticFleet, start: int) -> list[EpochInput]:
    """The fleet's epochs, without a Doppler velocity or drift from `start` on (a receiver with
    Doppler in an outage of it: its pseudoranges stay)."""
    out = []
    for k, e in enumerate(fleet.epochs):
        if k >= start:
            e = dataclasses.replace(
                e,
                vehicles={
                    v: dataclasses.replace(vin, velocity=None, clock_drift_mps=None)
                    for v, vin in e.vehicles.items()
                },
            )
        out.append(e)
    return out


def test_an_outage_can_extrapolate_the_last_doppler_velocity() -> None:
    """Off: after the outage's first epoch the link extrapolates the difference of the last two
    estimates; on: the last Doppler velocity, every epoch of the outage."""
    fleet = make_fleet(1, 9, seed=5, velocity_sigma=0.05)
    epochs = _outage_from(fleet, 5)
    velocity = fleet.epochs[4].vehicles["v01"].velocity
    assert velocity is not None
    last_doppler = np.asarray(velocity.velocity_mps)  # dt = 1 s
    moves: dict[bool, list[np.ndarray]] = {}
    for flag in (False, True):
        est = FusionEstimator(dataclasses.replace(_robust(), motion_last_doppler=flag))
        moves[flag] = []
        for epoch in epochs:
            est.step(epoch)
            links = est._state.window.by_vehicle["v01"][-1].links
            moves[flag] += [np.asarray(ln.factor().measured()) for ln in links if ln.kind == "motion"]
    assert len(moves[True]) == len(moves[False]) == 4
    for m in moves[True]:
        np.testing.assert_allclose(m, last_doppler, atol=1e-12)
    np.testing.assert_allclose(moves[False][0], last_doppler, atol=1e-12)  # the previous state's Doppler
    assert all(np.linalg.norm(m - last_doppler) > 1e-4 for m in moves[False][1:])


def test_an_outage_can_extrapolate_only_the_horizontal_velocity() -> None:
    """The Doppler velocity before an outage 1.4 m/s upward (NLOS at a canyon's entrance): the
    outage links extrapolate that climb, but with `outage_horizontal` none of it (the height is
    left to the fallback's vertical sigma)."""
    fleet = make_fleet(1, 9, seed=5, velocity_sigma=0.05)
    epochs = _outage_from(fleet, 5)
    before = epochs[4].vehicles["v01"]
    assert before.velocity is not None and before.spp_position is not None
    struck = before.velocity.velocity_mps + 1.4 * up_vector(before.spp_position)
    epochs[4] = dataclasses.replace(
        epochs[4],
        vehicles={
            "v01": dataclasses.replace(
                before, velocity=dataclasses.replace(before.velocity, velocity_mps=struck)
            )
        },
    )
    ups: dict[bool, list[float]] = {}
    for flag in (False, True):
        est = FusionEstimator(dataclasses.replace(_robust(), outage_horizontal=flag))
        ups[flag] = []
        for epoch in epochs:
            est.step(epoch)
            blocks = est._state.window.by_vehicle["v01"]
            for ln in blocks[-1].links:
                if ln.kind == "motion":
                    up = up_vector(est._state.position(blocks[-2].pos_key))
                    ups[flag].append(float(np.asarray(ln.factor().measured()) @ up))
    assert len(ups[True]) == len(ups[False]) == 4
    assert all(u > 1.0 for u in ups[False])  # the climb, carried through the outage
    np.testing.assert_allclose(ups[True], 0.0, atol=1e-4)  # up taken at the estimate since moved
