"""The paper's orderings measured on the bundled urban recording.

Margins, not exact numbers. The bundled recording (4 vehicles, 600 s, 1.5 laps of the urban loop)
is used rather than a shorter one because planes need the fleet's history: in the first lap the
leading vehicles have few solved positions within 50 m and planes are mostly unavailable.
Measured values are printed (-s) and tabulated in docs/results.md.
"""

from __future__ import annotations

import numpy as np
import pytest

from coplane.evaluate.front_ends import FrontEndMemo
from coplane.evaluate.report import run_stats
from coplane.evaluate.runner import run_method
from coplane.recording.reader import open_recording
from coplane.sim.generate import bundled_default_path

pytestmark = pytest.mark.slow

RUNS = [
    ("non-cp", 0.0),
    ("mci", 0.0),
    ("pc", 0.0),
    ("pc-no-ir", 0.0),
    ("mci", 1.0),
    ("pc", 1.0),
]


@pytest.fixture(scope="module")
def stats() -> dict[tuple[str, float], dict]:
    rec = open_recording(bundled_default_path())
    out = {}
    memo = FrontEndMemo()  # the GNSS front ends once for every run: the same bits, less CPU
    for method, rate in RUNS:
        run = run_method(rec, method, interruption=rate, jobs=1, front_ends=memo)
        out[(method, rate)] = run_stats(run, rec)
    for (m, r), st in out.items():
        row = "  ".join(f"{v}: H {s.h_rmse_m:.2f} V {s.v_rmse_m:.2f}" for v, s in st.items())
        print(f"{m}@{int(r * 100)}%: {row}")
    return out


def _h(st: dict, key: tuple[str, float]) -> dict[str, float]:
    return {v: s.h_rmse_m for v, s in st[key].items()}


def _v(st: dict, key: tuple[str, float]) -> dict[str, float]:
    return {v: s.v_rmse_m for v, s in st[key].items()}


def test_every_epoch_has_a_solution(stats: dict) -> None:
    for key, per in stats.items():
        for vid, s in per.items():
            assert s.availability > 0.99, (key, vid, s.availability)


def test_ranging_beats_standalone(stats: dict) -> None:
    h_non, h_mci = _h(stats, ("non-cp", 0.0)), _h(stats, ("mci", 0.0))
    v_non, v_mci = _v(stats, ("non-cp", 0.0)), _v(stats, ("mci", 0.0))
    for vid in h_non:
        assert h_mci[vid] < 0.9 * h_non[vid], vid  # clearly, for every vehicle
    # vertical: better for the fleet; not for every vehicle on this recording (u2 is worse with
    # UWB: docs/results.md discusses it), so the fleet mean is asserted
    assert np.mean(list(v_mci.values())) < np.mean(list(v_non.values()))


def test_planes_beat_ranging_most_in_the_vertical(stats: dict) -> None:
    h_mci, h_pc = _h(stats, ("mci", 0.0)), _h(stats, ("pc", 0.0))
    v_mci, v_pc = _v(stats, ("mci", 0.0)), _v(stats, ("pc", 0.0))
    # horizontally no worse for the fleet; per vehicle within what the last bits of the host's
    # SIMD paths move on this recording (docs/fgo.md, "Numerical sensitivity": u1 is pc 0.41 /
    # mci 0.48 m on an AVX-512 host and 0.47 / 0.42 m on an AVX2-only one, same code and kernels)
    assert np.mean(list(h_pc.values())) <= np.mean(list(h_mci.values())) + 0.02
    for vid in h_mci:
        assert h_pc[vid] <= h_mci[vid] + 0.1, vid
        assert v_pc[vid] < v_mci[vid], vid  # better vertically for every vehicle
    gain_h = 1 - np.mean(list(h_pc.values())) / np.mean(list(h_mci.values()))
    gain_v = 1 - np.mean(list(v_pc.values())) / np.mean(list(v_mci.values()))
    assert gain_v > 0.04 and gain_v > gain_h


def test_planes_alone_beat_standalone(stats: dict) -> None:
    """Planes without ranging (`pc-no-ir`) beat the standalone graph vertically and tie it
    horizontally. Measured V u1-u4 `pc-no-ir` 0.76 0.83 0.54 0.73 m against `non-cp` 0.92 0.93
    0.78 0.99 m, H within 0.02 m (u2 1.63 against 1.62 m); docs/results.md, bundled section of
    2026-11-27. The paper's "no FE" ablation (`pc-no-ir-no-fe`, not tested here) is 0.60 0.95
    0.48 0.79 m: with the estimator's own FDE and scaled point sigmas, unscreened planes lose only
    on u2."""
    v_non, v_pcnoir = _v(stats, ("non-cp", 0.0)), _v(stats, ("pc-no-ir", 0.0))
    h_non, h_pcnoir = _h(stats, ("non-cp", 0.0)), _h(stats, ("pc-no-ir", 0.0))
    for vid in v_non:
        assert v_pcnoir[vid] < 0.95 * v_non[vid], vid
        assert h_pcnoir[vid] <= h_non[vid] + 0.02, vid


def test_planes_keep_their_gain_without_any_ranging(stats: dict) -> None:
    v_mci, v_pc = _v(stats, ("mci", 1.0)), _v(stats, ("pc", 1.0))
    h_mci, h_pc = _h(stats, ("mci", 1.0)), _h(stats, ("pc", 1.0))
    for vid in v_mci:
        assert v_pc[vid] < 0.95 * v_mci[vid], vid
        assert h_pc[vid] <= h_mci[vid] + 0.02, vid
    # with no ranging at all, mci is exactly the standalone estimator
    assert _h(stats, ("mci", 1.0)) == pytest.approx(_h(stats, ("non-cp", 0.0)), abs=1e-9)
