"""RINEX observation reader on the hand-made corpus in tests/data/broken (see its README).

The clean files are checked against RTKLIB and georinex; every broken variant must give exactly
the clean data minus what its defect destroys (nothing lost, nothing invented) and report the
defect with the right kind and line.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import pytest
from support.rtklib_rinex_ref import read_obs_rtklib

from coplane.gtime import GpsTime
from coplane.recording.model import ObsEpoch
from coplane.recording.problems import Problems, RecordingError
from coplane.recording.rinex_obs import SignalCodes, read_obs

BROKEN = Path(__file__).resolve().parents[1] / "data" / "broken"

Row = tuple[float, float, float]  # pseudorange, doppler, cn0 (NaN where absent)
Table = dict[GpsTime, dict[str, Row]]


def table(epochs: list[ObsEpoch]) -> Table:
    return {e.time: {s.sat: (s.pseudorange_m, s.doppler_hz, s.cn0_dbhz) for s in e.sats} for e in epochs}


def read(name: str, **kw: object) -> tuple[Table, list[tuple[str, int | None]], list[ObsEpoch]]:
    problems = Problems()
    _, epochs = read_obs(BROKEN / name, problems, **kw)  # type: ignore[arg-type]
    return table(epochs), [(p.kind, p.line) for p in problems.items], epochs


def same(a: Table, b: Table) -> bool:
    """Equal tables, NaN == NaN."""
    if a.keys() != b.keys():
        return False
    for t in a:
        if a[t].keys() != b[t].keys():
            return False
        for s in a[t]:
            for x, y in zip(a[t][s], b[t][s], strict=True):
                if not (x == y or (math.isnan(x) and math.isnan(y))):
                    return False
    return True


@pytest.fixture(scope="module")
def clean() -> Table:
    tab, problems, _ = read("clean_v3.obs")
    assert problems == []
    return tab


def test_clean_v3_matches_rtklib(clean: Table) -> None:
    ref = read_obs_rtklib(BROKEN / "clean_v3.obs")
    assert list(ref) == list(clean)
    for t, sats in ref.items():
        assert set(sats) == set(clean[t])
        for sat, r in sats.items():
            pr, dop, cn0 = clean[t][sat]
            assert pr == pytest.approx(r.pseudorange_m, abs=1e-6)
            assert dop == pytest.approx(r.doppler_hz, abs=1e-3)
            assert cn0 == pytest.approx(r.snr_dbhz, abs=1e-3)


def test_clean_v3_matches_georinex(clean: Table) -> None:
    import georinex as gr

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        ds = gr.load(BROKEN / "clean_v3.obs", use={"G", "C"}, meas=["C1C", "D1C", "S1C", "C2I", "D2I", "S2I"])
    n = 0
    for i, t in enumerate(clean):
        for sat, (pr, dop, cn0) in clean[t].items():
            code = "C1C" if sat[0] == "G" else "C2I"
            dcode, scode = "D" + code[1:], "S" + code[1:]
            assert float(ds[code].isel(time=i).sel(sv=sat)) == pytest.approx(pr, abs=1e-6)
            assert float(ds[dcode].isel(time=i).sel(sv=sat)) == pytest.approx(dop, abs=1e-6)
            assert float(ds[scode].isel(time=i).sel(sv=sat)) == pytest.approx(cn0, abs=1e-6)
            n += 1
    assert n == sum(len(s) for s in clean.values())


@dataclass(frozen=True)
class Case:
    """A broken variant of clean_v3.obs: expected problems and what is lost (clean epoch indices)."""

    file: str
    problems: list[tuple[str, int | None]]
    drop_epochs: set[int] = field(default_factory=set)
    drop_sats: set[tuple[int, str]] = field(default_factory=set)
    nan_values: set[tuple[int, str, int]] = field(default_factory=set)  # (epoch, sat, 1=doppler 2=cn0)


DOP, CN0 = 1, 2
CASES = [
    Case("truncated_epoch_line.obs", [("malformed-epoch", 21)], drop_epochs={1}),
    Case(
        "bad_numbers.obs",
        [("bad-number", 22), ("bad-number", 25)],
        drop_sats={(1, "G05")},
        nan_values={(1, "C14", DOP)},
    ),
    Case(
        "nan_values.obs",
        [("nan-value", 27), ("nan-value", 29)],
        drop_sats={(2, "G05")},
        nan_values={(2, "G13", CN0)},
    ),
    Case(
        "absurd_pseudorange.obs",
        [("absurd-value", 18), ("absurd-value", 30)],
        drop_sats={(0, "G13"), (2, "C14")},
    ),
    Case(
        "snr_99.obs",
        [("absurd-value", 16), ("absurd-value", 19)],
        nan_values={(0, "G05", CN0), (0, "C14", CN0)},
    ),
    Case("non_monotonic.obs", [("non-monotonic-time", 26)], drop_epochs={2}),
    Case("garbage_middle.obs", [("malformed-line", 24), ("unexpected-line", 33)]),
    Case("missing_end_of_header.obs", [("missing-end-of-header", 14)]),
    Case("truncated_line.obs", [("truncated-line", 33)], drop_sats={(3, "G05")}),
    Case("truncated_file.obs", [("short-epoch", 34)], drop_sats={(3, "G13"), (3, "C14"), (3, "C01")}),
    Case("time_system_glo.obs", [("time-system", 13)]),
    Case("duplicate_satellite.obs", [("duplicate-satellite", 15)]),
    Case("event_flags_crlf.obs", []),
    Case("v302_beidou_c1i.obs", []),
]


def expected(clean: Table, case: Case) -> Table:
    out: Table = {}
    for i, (t, sats) in enumerate(clean.items()):
        if i in case.drop_epochs:
            continue
        row: dict[str, Row] = {}
        for sat, vals in sats.items():
            if (i, sat) in case.drop_sats:
                continue
            v = list(vals)
            for k in (DOP, CN0):
                if (i, sat, k) in case.nan_values:
                    v[k] = math.nan
            row[sat] = (v[0], v[1], v[2])
        out[t] = row
    return out


@pytest.mark.parametrize("case", CASES, ids=[c.file for c in CASES])
def test_broken_variant_loses_only_the_bad_part(clean: Table, case: Case) -> None:
    got, problems, _ = read(case.file)
    assert sorted(problems) == sorted(case.problems)
    assert same(got, expected(clean, case)), f"{case.file}: data around the defect changed"


def test_power_failure_epoch_kept_and_event_records_skipped() -> None:
    _, _, epochs = read("event_flags_crlf.obs")
    assert [e.flag for e in epochs] == [0, 1, 0, 0]
    # the flag-6 cycle-slip record carries a 99999999.0 "pseudorange" that must not appear
    assert all(s.pseudorange_m < 5e7 for e in epochs for s in e.sats)


@pytest.mark.parametrize("name", ["header_only_no_end.obs", "not_rinex.obs", "does_not_exist.obs"])
def test_unusable_file_raises_with_path(name: str) -> None:
    with pytest.raises(RecordingError, match=name.replace(".", r"\.")):
        read_obs(BROKEN / name, Problems())


def test_header_fields() -> None:
    header, _ = read_obs(BROKEN / "clean_v3.obs", Problems())
    assert header.version == 3.04
    assert header.marker_name == "BROKEN"
    assert header.receiver == "TESTRCV"
    assert header.antenna == "TESTANT         NONE"
    assert header.approx_position_ecef_m == (-3817680.9841, 3562840.0688, 3650158.4543)
    assert header.antenna_delta_hen_m == (0.1, 0.0, 0.0)
    assert header.obs_types["G"] == ("X1", "C1C", "L1C", "D1C", "S1C", "C2W")
    assert header.obs_types["E"] == ("C1C", "L1C", "D1C", "S1C")  # declared, no records
    assert header.interval_s == 1.0
    assert header.time_system == "GPS"


def test_selected_signals_are_configurable() -> None:
    """C2W instead of C1C for GPS, GLONASS added: values must match georinex's parse."""
    import georinex as gr

    signals = {"G": SignalCodes("C2W"), "R": SignalCodes("C1C", "D1C", "S1C")}
    got, problems, _ = read("clean_v3.obs", signals=signals, systems=("G", "R"))
    assert problems == []
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        ds = gr.load(BROKEN / "clean_v3.obs", use={"G", "R"}, meas=["C2W", "C1C", "D1C"])
    for i, (_, sats) in enumerate(got.items()):
        assert set(sats) == {"G05", "R07"}  # G13 has no C2W; C satellites not requested
        assert sats["G05"][0] == pytest.approx(float(ds["C2W"].isel(time=i).sel(sv="G05")), abs=1e-6)
        assert math.isnan(sats["G05"][1])  # no Doppler configured
        assert sats["R07"][0] == pytest.approx(float(ds["C1C"].isel(time=i).sel(sv="R07")), abs=1e-6)
        assert sats["R07"][1] == pytest.approx(float(ds["D1C"].isel(time=i).sel(sv="R07")), abs=1e-6)


def test_missing_signal_configuration_is_a_programming_error() -> None:
    with pytest.raises(ValueError, match="SignalCodes"):
        read_obs(BROKEN / "clean_v3.obs", Problems(), signals={"G": SignalCodes("C1C")}, systems=("G", "C"))


def test_rinex2_splice_and_continued_satellite_list_match_rtklib() -> None:
    got, problems, epochs = read("clean_v2.obs")
    assert problems == []
    assert len(epochs[0].sats) == 13  # 12 on the epoch line + 1 on the continuation line
    assert "G08" in got[epochs[0].time]  # blank system character means GPS
    ref = read_obs_rtklib(BROKEN / "clean_v2.obs")
    assert list(ref) == list(got)
    for t, sats in ref.items():
        assert set(sats) == set(got[t])
        for sat, r in sats.items():
            pr, dop, cn0 = got[t][sat]
            assert pr == pytest.approx(r.pseudorange_m, abs=1e-6)
            assert dop == pytest.approx(r.doppler_hz, abs=1e-3)
            assert cn0 == pytest.approx(r.snr_dbhz, abs=1e-3)


def test_rinex2_malformed_epoch_resyncs() -> None:
    clean2, _, _ = read("clean_v2.obs")
    got, problems, _ = read("v2_malformed_epoch.obs")
    assert problems == [("malformed-epoch", 41)]
    times = list(clean2)
    assert same(got, {t: clean2[t] for t in (times[0], times[2])})
