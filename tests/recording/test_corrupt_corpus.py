"""Issue 13's corpus: every command survives every corrupted recording (tests/support/corrupt_recordings).

The rule a user relies on: no traceback, bounded time and memory, and either a non-zero exit whose
message names the file, or a printed problem count. `spp` runs the whole corpus (it reads every
file and is quick); `eval` runs the defects that reach its own code paths (the replay grid, UWB
matching, the estimators). bench/reliability_recordings.py runs both on everything for the docs.
"""

from __future__ import annotations

import shutil
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import pytest
from support.corrupt_recordings import DEFECTS, make_corpus, run_one

from coplane.cli.render import STRICT_EXIT_CODE
from coplane.sim.generate import simulate

MAX_WALL_S = 30.0
MAX_RSS_MB = 1024.0
EVAL_DEFECTS = ("obs-year-2094", "obs-last-epoch-2094", "obs-long-line", "uwb-1e308", "nav-other-week")


@pytest.fixture(scope="module")
def corpus(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    root = tmp_path_factory.mktemp("corpus")
    clean = simulate("urban-loop", root / "clean", vehicles=2, duration_s=20, seed=7)
    made = make_corpus(clean, root / "broken")
    return {"clean": clean, **made}


@pytest.fixture(scope="module")
def coplane() -> str:
    exe = shutil.which("coplane") or str(Path(__file__).resolve().parents[2] / ".venv" / "bin" / "coplane")
    assert Path(exe).exists(), "the coplane command is not installed"
    return exe


def test_corpus_is_big_enough() -> None:
    assert len(DEFECTS) >= 20
    assert len({d.name for d in DEFECTS}) == len(DEFECTS)


def test_spp_survives_every_defect(corpus: dict[str, Path], coplane: str, tmp_path: Path) -> None:
    """Two at a time: the runs are independent processes, and CI has two cores."""
    with ThreadPoolExecutor(2) as pool:
        runs = list(
            pool.map(
                lambda d: run_one(coplane, "spp", d.name, corpus[d.name], tmp_path / d.name, True), DEFECTS
            )
        )
    bad = [r for r in runs if not r.ok or r.exit_code not in (0, 2, STRICT_EXIT_CODE)]
    assert not bad, "\n".join(map(str, bad))
    slow = [r for r in runs if r.wall_s >= MAX_WALL_S or r.peak_rss_mb >= MAX_RSS_MB]
    assert not slow, "\n".join(map(str, slow))


@pytest.mark.parametrize("defect", EVAL_DEFECTS)
def test_eval_survives(defect: str, corpus: dict[str, Path], coplane: str, tmp_path: Path) -> None:
    r = run_one(coplane, "eval", defect, corpus[defect], tmp_path, strict=True)
    assert r.ok, r
    assert r.wall_s < MAX_WALL_S and r.peak_rss_mb < MAX_RSS_MB, r


def test_strict_exit_codes(corpus: dict[str, Path], coplane: str, tmp_path: Path) -> None:
    """Clean input passes --strict; too many bad records or nothing positioned fail it (code 3),
    and without --strict the same runs only warn."""
    assert run_one(coplane, "spp", "clean", corpus["clean"], tmp_path, strict=True).exit_code == 0
    junk = run_one(coplane, "spp", "obs-binary-junk", corpus["obs-binary-junk"], tmp_path, strict=True)
    assert junk.exit_code == STRICT_EXIT_CODE and junk.problem_count
    stale = run_one(coplane, "spp", "nav-other-week", corpus["nav-other-week"], tmp_path, strict=True)
    assert stale.exit_code == STRICT_EXIT_CODE and stale.names_file, stale
    assert run_one(coplane, "spp", "obs-binary-junk", corpus["obs-binary-junk"], tmp_path).exit_code == 0
