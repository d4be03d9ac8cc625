"""`coplane map build | show` as a user runs them, and a map used by `coplane eval --map`."""

from __future__ import annotations

import json
from pathlib import Path

from typer.testing import CliRunner

from coplane.cli import app
from coplane.sim.generate import simulate
from coplane.store.roadmap_db import RoadMapDb

runner = CliRunner()


def test_build_twice_show_and_use(tmp_path: Path) -> None:
    rec = simulate("urban-loop", tmp_path / "rec", vehicles=2, duration_s=60, seed=12)
    out = tmp_path / "map.sqlite"
    r = runner.invoke(app, ["map", "build", str(rec), "--out", str(out)])
    assert r.exit_code == 0, r.output
    with RoadMapDb(out, readonly=True) as db:
        first = db.load()
    assert first.stats()["passes"] > 0 and set(first.mapped_until) == {"u1", "u2"}
    # the same recording again is the same evidence: nothing is added, and the output says why
    r = runner.invoke(app, ["map", "build", str(rec), "--out", str(out)])
    assert r.exit_code == 0 and "already-mapped" in r.output, r.output
    with RoadMapDb(out, readonly=True) as db:
        again = db.load()
    assert again.stats() == first.stats()
    r = runner.invoke(app, ["map", "show", str(out), "--out", str(tmp_path / "show")])
    assert r.exit_code == 0, r.output
    fc = json.loads((tmp_path / "show" / "tiles.geojson").read_text())
    assert fc["type"] == "FeatureCollection" and len(fc["features"]) == first.stats()["tiles"]
    assert (tmp_path / "show" / "tiles.png").stat().st_size > 1000
    r = runner.invoke(
        app, ["eval", str(rec), "--methods", "pc-self-map", "--map", str(out), "--out", str(tmp_path / "ev")]
    )
    assert r.exit_code == 0, r.output
    assert (tmp_path / "ev" / "accuracy.md").exists()


def test_a_standalone_drive_builds_no_map_and_says_why(tmp_path: Path) -> None:
    """Without a base station every reported vertical sigma carries the atmosphere's residual, which
    the whole drive shares (docs/roadmap.md, 'Without a base station'): the trust filter keeps none
    of it, and the build says so instead of writing an empty map silently."""
    rec = simulate("urban-loop", tmp_path / "rec", vehicles=2, duration_s=60, seed=12)
    out = tmp_path / "map.sqlite"
    r = runner.invoke(app, ["map", "build", str(rec), "--out", str(out), "--no-dgnss"])
    assert r.exit_code == 0, r.output
    said = " ".join(r.output.split())  # rich wraps at the terminal's width
    assert "no sample passed the map's trust filter (sigma-up 120)" in said, r.output
    assert "without a base station" in said, r.output
    with RoadMapDb(out, readonly=True) as db:
        assert db.load().stats()["passes"] == 0


def test_eval_refuses_a_map_no_method_reads_and_map_methods_without_one(tmp_path: Path) -> None:
    """Both stop before any method runs: a map beside only map-less methods would give tables that
    silently ignore it, and `pc,pc-map` without a map used to fail only after `pc` had run."""
    rec = simulate("urban-loop", tmp_path / "rec", vehicles=1, duration_s=5, seed=3)
    out = tmp_path / "map.sqlite"
    RoadMapDb(out).close()  # an empty map: enough, the refusal comes before it is read
    ev = tmp_path / "ev"
    r = runner.invoke(app, ["eval", str(rec), "--methods", "pc", "--map", str(out), "--out", str(ev)])
    said = " ".join(r.output.split())
    assert r.exit_code != 0 and "none of the methods reads one" in said, r.output
    r = runner.invoke(app, ["eval", str(rec), "--methods", "pc,pc-map,pc-self-map", "--out", str(ev)])
    said = " ".join(r.output.split())
    assert r.exit_code != 0 and "pc-map, pc-self-map take their planes from a road-surface map" in said
    assert not (ev / "solutions").exists()  # nothing ran
    # a missing recording among several is named before any is built into the map
    fresh = tmp_path / "fresh.sqlite"
    r = runner.invoke(app, ["map", "build", str(rec), str(tmp_path / "nope"), "--out", str(fresh)])
    said = "".join(r.output.split())  # rich wraps, and folds a long path anywhere
    assert r.exit_code == 2 and "nope:nosuchdirectory" in said and not fresh.exists()
