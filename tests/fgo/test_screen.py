"""The estimator's fault detection and exclusion before the graph (`coplane.fgo.screen`)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from coplane.estimation.validate import ValidPseudoranges
from coplane.fgo.config import FgoConfig
from coplane.fgo.prepare import diverged, lacks_redundancy, screen
from coplane.fgo.screen import ScreenResult, screen_pseudoranges, weak_rows
from coplane.fgo.state import StepStats
from coplane.geo import enu_rotation, geodetic_to_ecef
from coplane.gnss.constants import C

LAT, LON = np.radians(39.98), np.radians(116.31)
RX = geodetic_to_ecef(LAT, LON, 50.0)
CLOCK_M = 1234.5


def _epoch(
    n: int, sigma: float, rng: np.random.Generator, bias: dict[int, float] | None = None
) -> ValidPseudoranges:
    """n GPS satellites spread over the sky, pseudoranges with N(0, sigma) noise (+ biases)."""
    r = enu_rotation(LAT, LON)  # rows: E, N, U in ECEF
    az = np.linspace(0.0, 2 * np.pi, n, endpoint=False) + 0.3
    el = np.radians(np.linspace(20.0, 80.0, n))
    los_enu = np.stack([np.cos(el) * np.sin(az), np.cos(el) * np.cos(az), np.sin(el)], axis=1)
    sats = RX + 2.2e7 * (los_enu @ r)
    rho = np.linalg.norm(sats - RX, axis=1) + CLOCK_M + rng.normal(0.0, sigma, n)
    for i, b in (bias or {}).items():
        rho[i] += b
    return ValidPseudoranges(
        [f"G{i + 1:02d}" for i in range(n)],
        ["G"] * n,
        sats,
        rho,
        np.zeros(n),
        np.full(n, sigma),
        el,
        np.full(n, 45.0),
    )


@pytest.mark.parametrize(("k_long", "limit"), [(None, 6), (2.5, 30)])
def test_clean_epochs_keep_every_satellite_almost_always(k_long: float | None, limit: int) -> None:
    """The w-test at 3.29 sigma: about 1e-3 false alarms per satellite (measured 1 of 2000). A
    long-side threshold of 2.5 costs more: measured 15 of 2000 (2.0: 52), the price docs/fgo.md
    weighs against what it catches ("One-sided FDE")."""
    rng = np.random.default_rng(1)
    n_out = 0
    for _ in range(200):
        prs = _epoch(10, 3.0, rng)
        res = screen_pseudoranges(prs, RX + rng.normal(0, 1.0, 3), np.eye(3) * 4.0, 3.29, k_long=k_long)
        n_out += int((~res.keep).sum())
        assert not res.prediction_rejected
    assert n_out <= limit  # of 2000 satellite tests


def test_one_nlos_bias_is_excluded_and_the_rest_kept() -> None:
    rng = np.random.default_rng(2)
    for trial in range(20):
        prs = _epoch(8, 3.0, rng, {trial % 8: 35.0})
        res = screen_pseudoranges(prs, RX, np.eye(3) * 4.0, 3.29)
        assert not res.keep[trial % 8]
        assert int(res.keep.sum()) >= 6


def test_the_prior_makes_a_fault_visible_with_five_satellites() -> None:
    """Five satellites, four unknowns: snapshot RAIM could detect but not identify; the predicted
    position with its covariance adds the redundancy."""
    rng = np.random.default_rng(3)
    hits = 0
    for trial in range(20):
        prs = _epoch(5, 2.0, rng, {trial % 5: 40.0})
        res = screen_pseudoranges(prs, RX, np.eye(3) * 1.0, 3.29)
        hits += int(not res.keep[trial % 5])
        assert int(res.keep.sum()) >= 4
    assert hits >= 18


def test_a_wrong_prediction_excludes_nothing() -> None:
    """Most satellites fail against a prediction 80 m off with a tight prior: the prediction is
    what is wrong (a diverged state), so the epoch is kept whole and flagged."""
    rng = np.random.default_rng(4)
    prs = _epoch(10, 3.0, rng)
    res = screen_pseudoranges(prs, RX + np.array([80.0, -40.0, 30.0]), np.eye(3) * 1.0, 3.29)
    assert res.prediction_rejected and bool(res.keep.all())


def test_a_wrong_prediction_falls_back_to_snapshot_raim() -> None:
    """With `snapshot_fallback` the rejected prediction is dropped, not the test: the epoch's own
    redundancy still finds an NLOS range, and a clean epoch stays whole."""
    rng = np.random.default_rng(5)
    off = RX + np.array([80.0, -40.0, 30.0])
    for trial in range(10):
        prs = _epoch(10, 3.0, rng, {trial % 10: 60.0})
        res = screen_pseudoranges(prs, off, np.eye(3) * 1.0, 3.29, snapshot_fallback=True)
        assert res.prediction_rejected
        assert not res.keep[trial % 10] and int(res.keep.sum()) >= 8
    clean = screen_pseudoranges(_epoch(10, 3.0, rng), off, np.eye(3) * 1.0, 3.29, snapshot_fallback=True)
    assert clean.prediction_rejected and int(clean.keep.sum()) >= 9


@pytest.mark.parametrize("n", [4, 5, 6])
def test_never_below_four(n: int) -> None:
    rng = np.random.default_rng(5)
    prs = _epoch(n, 3.0, rng, {i: 50.0 * (i + 1) for i in range(n - 2)})
    res = screen_pseudoranges(prs, RX, np.eye(3) * 4.0, 3.29)
    assert int(res.keep.sum()) >= min(n, 4)


def test_clock_offsets_per_system_do_not_count_as_faults() -> None:
    """A large receiver clock (and a different one per system) is absorbed, not tested."""
    rng = np.random.default_rng(6)
    prs = _epoch(10, 3.0, rng)
    prs.rho[5:] += 7e4  # a second "system" with its own clock
    prs = ValidPseudoranges(
        prs.sats,
        ["G"] * 5 + ["C"] * 5,
        prs.sat_pos,
        prs.rho,
        prs.sat_clock / C,
        prs.sigma,
        prs.elevation,
        prs.cn0,
    )
    res = screen_pseudoranges(prs, RX, np.eye(3) * 4.0, 3.29)
    assert bool(res.keep.all())


def test_a_fault_in_a_two_satellite_system_excludes_both_whatever_the_row_order() -> None:
    """Two satellites of a system with its own clock: their w-tests are one test (equal |w|), so
    the data cannot say which holds the fault. Both go, and the kept set does not depend on
    rounding or row order (one of them was picked by rounding before; docs/fgo.md)."""
    rng = np.random.default_rng(7)
    base = _epoch(8, 1.0, rng, {6: 30.0})
    systems = ["C"] * 6 + ["G"] * 2
    kept = []
    for order in (np.arange(8), np.arange(8)[::-1], rng.permutation(8)):
        prs = ValidPseudoranges(
            [base.sats[i] for i in order],
            [systems[i] for i in order],
            base.sat_pos[order],
            base.rho[order],
            base.sat_clock[order],
            base.sigma[order],
            base.elevation[order],
            base.cn0[order],
        )
        res = screen_pseudoranges(prs, RX, np.eye(3) * 4.0, 3.29)
        kept.append({prs.sats[i] for i in np.flatnonzero(res.keep)})
        assert len(res.excluded_w) == 2
        assert res.excluded_w[0] == pytest.approx(res.excluded_w[1], rel=1e-9)
    assert kept[0] == kept[1] == kept[2] == set(base.sats[:6])


def test_a_young_track_is_screened_against_its_reported_covariance() -> None:
    """`fde_warmup_epochs` (off by default, docs/fgo.md): a track started 12 m off, with the
    graph's 2 m covariance, loses clean satellites to the w-test; its first epochs are
    screened against the honest (reported, x covariance_scale^2) covariance instead, or without
    a prior, and keep them."""
    rng = np.random.default_rng(5)
    prs = _epoch(5, 1.0, rng)  # too few to reject the prediction: the w-test runs against it
    off = RX + np.array([12.0, 0.0, 0.0])
    cov = np.eye(3) * 4.0
    base = FgoConfig(fde_k=3.29, fde_snapshot_fallback=True, covariance_scale=4.5, fde_warmup_epochs=10)
    old, _, _ = screen(prs, off, cov, 0.1, base, StepStats(), young=False)
    assert len(old) < len(prs)
    for prior in ("reported", "snapshot"):
        cfg = dataclasses.replace(base, fde_warmup_prior=prior)
        assert len(screen(prs, off, cov, 0.1, cfg, StepStats(), young=True)[0]) == len(prs), prior
    with pytest.raises(ValueError, match="fde_warmup_epochs"):
        FgoConfig(fde_warmup_epochs=-1)


def test_a_lower_threshold_on_the_long_side_catches_a_smaller_nlos_bias() -> None:
    """`k_long` tests residuals measured too long (NLOS) against a lower threshold: a 3.5-sigma
    bias that lengthens a range is caught far more often at k_long 2.0 than at 3.29. Without
    noise, a 5-sigma bias is excluded when it lengthens the range, at k_long 2.0 (and at 3.29),
    and a 3-sigma bias that shortens it stays at 3.29 on that side (NLOS cannot shorten)."""
    caught = plain = 0
    for trial in range(40):
        prs = _epoch(10, 1.0, np.random.default_rng(trial), bias={3: 3.5})
        caught += int(not screen_pseudoranges(prs, RX, np.eye(3) * 0.25, 3.29, k_long=2.0).keep[3])
        plain += int(not screen_pseudoranges(prs, RX, np.eye(3) * 0.25, 3.29).keep[3])
    assert caught >= 30 and caught > plain + 10, (caught, plain)
    for bias, k_long, out in ((5.0, 2.0, True), (-3.0, 2.0, False), (-3.0, None, False)):
        prs = _epoch(10, 1e-9, np.random.default_rng(0), bias={3: bias})
        prs = dataclasses.replace(prs, sigma=np.ones(len(prs)))
        res = screen_pseudoranges(prs, RX, np.eye(3) * 0.25, 3.29, k_long=k_long)
        assert (not res.keep[3]) is out, (bias, k_long, res.keep)
    # what is reported is the standardised residual itself (measured 4.54), not the statistic
    # scaled onto 3.29 for the long side
    same = _epoch(10, 1e-9, np.random.default_rng(0), bias={3: 5.0})
    same = dataclasses.replace(same, sigma=np.ones(len(same)))
    w = [screen_pseudoranges(same, RX, np.eye(3) * 0.25, 3.29, k_long=k).excluded_w for k in (None, 2.0)]
    assert w[0] == pytest.approx(w[1]) and 4.0 < w[0][0] < 5.0, w


def test_the_long_side_threshold_can_be_kept_to_weak_satellites() -> None:
    """`long_rows` keeps `k_long` to the satellites likely to be NLOS: a 3-sigma lengthening
    is excluded on a weak satellite and kept on a strong one (the symmetric 3.29 passes it there).
    Weak means low or faint (absolute, or under the epoch's strongest satellite); an unreported
    elevation or C/N0 is not evidence."""
    prs = _epoch(10, 1e-9, np.random.default_rng(0), bias={3: 3.0})
    prs = dataclasses.replace(prs, sigma=np.ones(len(prs)))
    for weak, out in ((True, True), (False, False)):
        mask = np.zeros(len(prs), dtype=bool)
        mask[3] = weak
        res = screen_pseudoranges(prs, RX, np.eye(3) * 0.25, 3.29, k_long=2.0, long_rows=mask)
        assert (not res.keep[3]) is out, (weak, res.keep)
    # two-sided: the same threshold for a shortening on that satellite too (unbiased for
    # symmetric noise); one-sided, a shortening keeps the symmetric 3.29
    short = _epoch(10, 1e-9, np.random.default_rng(0), bias={3: -3.0})
    short = dataclasses.replace(short, sigma=np.ones(len(short)))
    mask = np.zeros(len(short), dtype=bool)
    mask[3] = True
    for two_sided, out in ((True, True), (False, False)):
        res = screen_pseudoranges(
            short, RX, np.eye(3) * 0.25, 3.29, k_long=2.0, long_rows=mask, two_sided=two_sided
        )
        assert (not res.keep[3]) is out, (two_sided, res.keep)
    cn0 = np.array([30.0, 45.0, np.nan, 45.0, 45.0, 45.0, 45.0, 45.0, 45.0, 45.0])
    el = np.radians([60.0, 60.0, 60.0, 10.0, np.nan, 60.0, 60.0, 60.0, 60.0, 60.0])
    faint_or_low = dataclasses.replace(prs, cn0=cn0, elevation=el)
    assert weak_rows(faint_or_low, 20.0, 35.0).tolist() == [True, False, False, True] + [False] * 6
    assert weak_rows(faint_or_low, None, 35.0).tolist() == [True] + [False] * 9
    assert weak_rows(faint_or_low, 20.0, None).tolist() == [False] * 3 + [True] + [False] * 6
    assert weak_rows(faint_or_low, None, None).all()
    # relative to the epoch's strongest satellite (45): the same satellites on a receiver whose
    # levels are all 12 dB lower, where an absolute 35 dB-Hz would call every satellite weak
    assert weak_rows(faint_or_low, below_best_cn0_db=12.0).tolist() == [True] + [False] * 9
    quiet = dataclasses.replace(faint_or_low, cn0=cn0 - 12.0)
    assert weak_rows(quiet, below_best_cn0_db=12.0).tolist() == [True] + [False] * 9
    assert weak_rows(quiet, below_cn0_dbhz=35.0).sum() == 9
    unreported = dataclasses.replace(faint_or_low, cn0=np.full(10, np.nan))
    assert not weak_rows(unreported, below_best_cn0_db=12.0).any()
    with pytest.raises(ValueError, match="fde_long_below_cn0_dbhz"):
        FgoConfig(fde_long_below_cn0_dbhz=-1.0)


def test_gtsam_asymmetric_kernels_act_on_the_distance_not_the_sign() -> None:
    """Why the asymmetry lives in the FDE (docs/fgo.md): GTSAM 4.3's robust noise model gives its
    mEstimator the Mahalanobis distance, which is never negative, so `AsymmetricCauchy`
    down-weights both signs of a 1-D error exactly like `Cauchy`. If a GTSAM release changes
    that, this test says so."""
    import gtsam

    est = gtsam.noiseModel.mEstimator
    sigma = gtsam.noiseModel.Isotropic.Sigma(1, 2.0)
    asym = gtsam.noiseModel.Robust.Create(est.AsymmetricCauchy.Create(1.0), sigma)
    sym = gtsam.noiseModel.Robust.Create(est.Cauchy.Create(1.0), sigma)
    for e in (4.0, -4.0):
        assert asym.whiten(np.array([e]))[0] == pytest.approx(sym.whiten(np.array([e]))[0])
        assert abs(asym.whiten(np.array([e]))[0]) < 0.5 * abs(e) / 2.0  # down-weighted, both signs


def test_a_diverged_prediction_is_rejected_when_exclusions_pile_up() -> None:
    """A prediction 60 m off held with a 2 m covariance (a track after a long stretch on 3
    satellites): the first w-test fits most of the offset and fails fewer than half of the 17
    rows, and the iterated test then strips the epoch down to the few rows that agree with the
    prior. Counting the exclusions (`count_exclusions`, FgoConfig.fde_reject_on_exclusions)
    rejects the prediction instead, and the snapshot fallback keeps the clean epoch whole."""
    prs = _epoch(17, 3.0, np.random.default_rng(7))
    r = enu_rotation(LAT, LON)
    off = RX + np.array([21.0, 60.0, 6.0]) @ r
    cov = np.eye(3) * 4.0
    plain = screen_pseudoranges(prs, off, cov, 3.29, snapshot_fallback=True)
    assert not plain.prediction_rejected and int(plain.keep.sum()) <= 4
    counted = screen_pseudoranges(prs, off, cov, 3.29, snapshot_fallback=True, count_exclusions=True)
    assert counted.prediction_rejected and bool(counted.keep.all())
    clean = screen_pseudoranges(prs, RX, cov, 3.29, snapshot_fallback=True, count_exclusions=True)
    assert not clean.prediction_rejected and bool(clean.keep.all())


def test_a_track_is_restarted_only_when_the_clean_fit_lies_far_outside_the_prediction() -> None:
    """`prepare.diverged` (FgoConfig.fde_restart_chi2): the squared Mahalanobis distance of the
    epoch's own fit from the prediction, the fit's covariance scaled up by its variance factor."""
    cfg = FgoConfig(fde_restart_chi2=400.0)
    keep = np.ones(12, dtype=bool)
    far = ScreenResult(keep, (), True, 0.5, None, np.array([80.0, 0.0, 0.0]), np.eye(3) * 4.0)
    p_pred = np.eye(3) * 4.0
    assert diverged(far, p_pred, cfg)  # 80^2 / 8 = 800
    assert not diverged(dataclasses.replace(far, prediction_rejected=False), p_pred, cfg)
    assert not diverged(far, p_pred, FgoConfig())  # off unless set
    assert not diverged(dataclasses.replace(far, variance_factor=3.0), p_pred, cfg)  # 6400 / 16 = 400
    assert not diverged(dataclasses.replace(far, offset_m=np.array([40.0, 0.0, 0.0])), p_pred, cfg)
    with pytest.raises(ValueError, match="fde_restart_chi2"):
        FgoConfig(fde_restart_chi2=0.0)


def test_a_far_snapshot_of_a_track_that_had_redundancy_is_not_believed() -> None:
    """`FgoConfig.fde_snapshot_max_chi2` (50 in ROBUST_FGO): a deep canyon where 9 of 17 rows carry NLOS
    delays of 20-60 m and the prediction is right (2 m sigma). The prediction is rejected, and
    snapshot RAIM keeps a subset whose fit lies far from it (chi2 480). Beyond the limit a track
    without a weak epoch is trusted instead: the prior-aided test keeps the clean rows. A track
    with a weak epoch (`may_restart`: its prediction may be the wrong one) keeps the snapshot, and
    restarts at its fit when it is beyond `fde_restart_chi2`."""
    rng = np.random.default_rng(2)
    prs = _epoch(17, 1.0, rng)
    nlos = np.arange(17) % 2 == 0
    prs = dataclasses.replace(prs, rho=prs.rho + np.where(nlos, rng.uniform(20.0, 60.0, 17), 0.0))
    clean = {s for s, n in zip(prs.sats, nlos, strict=True) if not n}
    cov = np.eye(3) * 4.0
    base = FgoConfig(
        fde_k=3.29, fde_snapshot_fallback=True, fde_reject_on_exclusions=True, fde_restart_chi2=400.0
    )

    snap, _, _ = screen(prs, RX, cov, 0.1, base, StepStats())
    assert set(snap.sats) != clean  # by default the snapshot's rows, however far its fit

    stats = StepStats()
    cfg = dataclasses.replace(base, fde_snapshot_max_chi2=50.0)
    kept, _, restart = screen(prs, RX, cov, 0.1, cfg, stats)
    assert set(kept.sats) == clean
    assert restart is None and stats.rejected["fde_snapshot_disbelieved"] == 1
    assert stats.rejected["fde_prediction_rejected"] == 1  # the rejection is counted all the same

    kept, _, restart = screen(prs, RX, cov, 0.1, cfg, StepStats(), may_restart=True)
    assert set(kept.sats) == set(snap.sats) and restart is not None
    with pytest.raises(ValueError, match="fde_snapshot_max_chi2"):
        FgoConfig(fde_snapshot_max_chi2=-1.0)


def test_an_epoch_the_prediction_cannot_vouch_for_is_dead_reckoned() -> None:
    """`FgoConfig.fde_snapshot_dead_reckon` (on in ROBUST_FGO): as above, but with delays for which the
    prior-aided test, its clock free, strips the epoch to the 4 rows that agree with a clock the
    NLOS majority pulled. Those 4 rows once made the window "without redundancy" and armed a
    restart at an NLOS fit (docs/fgo.md); with the option the epoch keeps no pseudorange."""
    rng = np.random.default_rng(0)
    prs = _epoch(17, 1.0, rng)
    nlos = np.arange(17) % 2 == 0
    prs = dataclasses.replace(prs, rho=prs.rho + np.where(nlos, rng.uniform(20.0, 60.0, 17), 0.0))
    cov = np.eye(3) * 4.0
    cfg = FgoConfig(
        fde_k=3.29,
        fde_snapshot_fallback=True,
        fde_reject_on_exclusions=True,
        fde_restart_chi2=400.0,
        fde_snapshot_max_chi2=50.0,
    )
    stripped, _, _ = screen(prs, RX, cov, 0.1, cfg, StepStats())
    assert len(stripped) == cfg.min_fix_pseudoranges

    stats = StepStats()
    kept, w, restart = screen(
        prs, RX, cov, 0.1, dataclasses.replace(cfg, fde_snapshot_dead_reckon=True), stats
    )
    assert len(kept) == 0 and restart is None and (w is None or len(w) == 0)
    assert stats.rejected["fde_dead_reckoned"] == 1 and stats.rejected["fde_snapshot_disbelieved"] == 1


def test_a_held_clock_keeps_the_clean_rows_of_an_nlos_majority() -> None:
    """`FgoConfig.fde_clock_prior` (opt-in): the epoch above, whose NLOS majority pulls a free
    clock to its side so that only 4 rows survive, keeps its clean rows when the clock is held to
    its prediction (the free clock kept 2 NLOS rows among its 4; the held one keeps only clean
    ones); a prediction off by a clock jump is ignored and the clock stays free."""
    rng = np.random.default_rng(0)
    prs = _epoch(17, 1.0, rng)
    nlos = np.arange(17) % 2 == 0
    prs = dataclasses.replace(prs, rho=prs.rho + np.where(nlos, rng.uniform(20.0, 60.0, 17), 0.0))
    cov = np.eye(3) * 4.0
    free = screen_pseudoranges(prs, RX, cov, 3.29, divergence_min=18)
    assert int(free.keep.sum()) == 4
    held = screen_pseudoranges(prs, RX, cov, 3.29, divergence_min=18, clock_prior={"G": (CLOCK_M, 2.0)})
    assert not (held.keep & nlos).any() and int(held.keep.sum()) >= 5  # measured: 5 of the 8 clean
    jumped = {"G": (CLOCK_M + 3e5, 2.0)}  # a 1 ms clock step
    assert bool(
        np.array_equal(
            screen_pseudoranges(
                prs, RX, cov, 3.29, divergence_min=18, clock_prior=jumped, clock_jump_m=1000.0
            ).keep,
            free.keep,
        )
    )


def test_only_unchecked_epochs_make_a_window_lack_redundancy() -> None:
    """`prepare.lacks_redundancy`, the restart's second condition: an epoch with at most 4
    pseudoranges counts; one the FDE dead-reckoned on purpose (`fde_dropped`) does not, unless
    three of the window's epochs were dead-reckoned."""

    @dataclasses.dataclass
    class Block:
        n_pseudoranges: int
        fde_dropped: bool = False

    assert not lacks_redundancy([Block(12), Block(9)], 4)
    assert lacks_redundancy([Block(12), Block(4)], 4)
    assert lacks_redundancy([Block(12), Block(0)], 4)  # an underpass
    assert not lacks_redundancy([Block(12), Block(0, True), Block(0, True)], 4)
    assert lacks_redundancy([Block(0, True), Block(0, True), Block(0, True)], 4)
