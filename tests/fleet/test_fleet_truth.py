"""`coplane fleet --truth rtk`: the moving real car replayed as a fleet over Zenoh, measured against
RTKLIB's RTK reference (`coplane.evaluate.rtk_reference`) in the launcher's table and in the API."""

from __future__ import annotations

from pathlib import Path

import httpx
import pytest

from coplane.api.app import _fleet_of
from coplane.api.settings import ApiSettings
from coplane.errors import ConfigError
from coplane.evaluate.evaluation import evaluate
from coplane.evaluate.rtk_reference import use_rtk_truth
from coplane.evaluate.truth import save_truth
from coplane.fleet import FleetOptions, free_port, run_fleet
from coplane.fleet.launcher import fleet_services
from coplane.recording.problems import Problems
from coplane.recording.reader import open_recording
from coplane.recording.trajectories import Q_DGPS, read_pos

pytestmark = [pytest.mark.slow, pytest.mark.realdata]

KLT = "hk_klt_20210610_f9p_rover_hksc_base"
TST = "urbannav_hk_tst_20200603_static_f9p"


def test_fleet_measures_the_car_against_its_rtk_reference(real_data: Path, tmp_path: Path) -> None:
    """The table, the API (handed the launcher's reference, listening before the first epoch) and
    `coplane eval` give the same numbers; `--out` with `--format pos` writes the solutions as
    RTKLIB .pos too, one row per solved epoch, DGNSS (Q 4) with the base."""
    port, seen = free_port(), []
    res = run_fleet(
        FleetOptions(
            recording=real_data / KLT,
            method="non-cp",
            api_port=port,
            certs=tmp_path / "certs",
            map=Path("none"),
            port=0,
            truth="rtk",
            out=tmp_path / "out",
            formats=frozenset({"pos"}),
        ),
        serve=lambda _: seen.extend(
            httpx.get(f"http://127.0.0.1:{port}/accuracy", timeout=10).json()["entries"]
        ),
    )
    assert "not a surveyed truth" in res.truth_note
    assert res.truth_vehicles == ["klt1"]
    st = res.stats["klt1"]
    # the same numbers as `coplane eval --truth rtk`: lockstep over the bus is the in-process replay
    ref = evaluate(open_recording(real_data / KLT), ["non-cp"], truth="rtk").stats["non-cp"]["klt1"]
    assert (st.n_truth, st.n_solved) == (ref.n_truth, ref.n_solved) and st.n_truth >= 60
    assert st.h_rmse_m == ref.h_rmse_m and st.v_rmse_m == ref.v_rmse_m
    (api,) = seen
    assert (api["n_truth"], api["n_solved"]) == (st.n_truth, st.n_solved)
    assert api["h_rmse_m"] == pytest.approx(st.h_rmse_m, abs=1e-4)  # the files keep 0.1 mm
    assert api["v_rmse_m"] == pytest.approx(st.v_rmse_m, abs=1e-4)
    pos = read_pos(tmp_path / "out" / "solutions" / "non-cp" / "klt1.pos", Problems())
    assert len(pos) == len(res.run.positions["klt1"]) and {p.quality for p in pos} == {Q_DGPS}


def test_the_api_and_the_launcher_carry_the_rtk_truth(real_data: Path, tmp_path: Path) -> None:
    _, vehicles, truth = _fleet_of(ApiSettings(recording=real_data / KLT, truth="rtk"))
    assert vehicles == ["klt1"] and len(truth["klt1"]) >= 60
    _, _, none = _fleet_of(ApiSettings(recording=real_data / KLT))
    assert none["klt1"] == {}  # the recording itself has no rover truth
    # the launcher makes the reference once and hands the API its files: the same epochs and positions
    rec = open_recording(real_data / KLT)
    use_rtk_truth(rec)
    handed = save_truth(rec, tmp_path / "truth")
    _, _, files = _fleet_of(ApiSettings(recording=real_data / KLT, truth_dir=handed))
    assert files["klt1"].keys() == truth["klt1"].keys()
    assert (
        max(
            max(abs(a - b) for a, b in zip(p, truth["klt1"][t], strict=True))
            for t, p in files["klt1"].items()
        )
        < 1e-4
    )
    specs = {
        s.name: s
        for s in fleet_services(
            real_data / KLT, "non-cp", "lockstep", 1.0, "tcp/x:1", ["klt1"], True, truth_dir=handed
        )
    }
    assert specs["api"].args[-2:] == ["--truth_dir", str(handed)]
    with pytest.raises(ConfigError, match="no \\[base\\]"):
        run_fleet(FleetOptions(recording=real_data / TST, api=False, insecure=True, truth="rtk"))
