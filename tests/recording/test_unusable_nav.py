"""A recording whose navigation files hold no ephemeris is refused with a message naming them
(it used to give 0 fixes and exit code 0)."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from coplane.recording.problems import RecordingError
from coplane.recording.reader import open_recording
from coplane.sim.generate import simulate


def test_header_only_nav_is_an_error_naming_the_file(tmp_path: Path) -> None:
    rec_dir = simulate("urban-loop", tmp_path / "r", vehicles=1, duration_s=5.0, seed=2)
    nav = rec_dir / "nav" / "brdc.rnx"
    header = nav.read_text().split("END OF HEADER")[0] + "END OF HEADER\n"
    nav.write_text(header)
    rec = open_recording(rec_dir)
    with pytest.raises(RecordingError, match=r"no usable broadcast ephemeris.*brdc\.rnx"):
        _ = rec.nav
    shutil.rmtree(rec_dir)
