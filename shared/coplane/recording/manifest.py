"""fleet.toml: load (validated, every path resolved inside the recording) and write.

A recording is untrusted input, so the manifest is the gate: a missing required key, an unknown
`format`, a bad or duplicate vehicle id, a path that leaves the recording directory (`..`,
absolute paths, symlinks pointing out) or a file that does not exist is a RecordingError that
names the key or path. Unknown keys are ignored (forward compatibility).
"""

from __future__ import annotations

import math
import os
import tomllib
from pathlib import Path
from typing import Any

import tomli_w

from coplane.ids import is_vehicle_id
from coplane.recording.model import BaseSpec, Manifest, UwbSpec, VehicleSpec
from coplane.recording.problems import RecordingError

FORMAT = "fleet-recording/1"
MANIFEST_NAME = "fleet.toml"


class _Ctx:
    """Where we are (manifest path) so every error names the file and the key."""

    def __init__(self, root: Path, toml_path: Path) -> None:
        self.root = root
        self.toml = toml_path

    def error(self, key: str, reason: str) -> RecordingError:
        return RecordingError(f"{self.toml}: {key}: {reason}")

    def require(self, table: dict[str, Any], key: str, where: str) -> Any:
        if key not in table:
            raise self.error(where, "required key is missing")
        return table[key]

    def table(self, value: Any, where: str) -> dict[str, Any]:
        if not isinstance(value, dict):
            raise self.error(where, "must be a table")
        return value

    def number(self, value: Any, where: str, positive: bool = False) -> float:
        if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
            raise self.error(where, f"must be a finite number, not {value!r}")
        if positive and value <= 0:
            raise self.error(where, f"must be positive, not {value!r}")
        return float(value)

    def string(self, value: Any, where: str) -> str:
        if not isinstance(value, str):
            raise self.error(where, f"must be a string, not {value!r}")
        return value

    def path(self, value: Any, where: str) -> Path:
        """A relative path inside the recording that exists (resolved, symlinks followed)."""
        rel = self.string(value, where)
        if not rel.strip():
            raise self.error(where, "empty path")
        p = (self.root / rel).resolve()
        if not p.is_relative_to(self.root):
            raise self.error(where, f"path {rel!r} leaves the recording directory {self.root}")
        if not p.is_file():
            raise self.error(where, f"file {rel!r} does not exist ({p})")
        return p

    def xyz(self, value: Any, where: str) -> tuple[float, float, float]:
        if not isinstance(value, list) or len(value) != 3:
            raise self.error(where, f"must be a list of 3 numbers, not {value!r}")
        x, y, z = (self.number(v, where) for v in value)
        return (x, y, z)


def _root_and_toml(root: Path) -> tuple[Path, Path]:
    root = Path(root)
    toml_path = root if root.name == MANIFEST_NAME or root.suffix == ".toml" else root / MANIFEST_NAME
    if not toml_path.parent.is_dir():  # a typo in the path: init cannot help there
        raise RecordingError(f"{toml_path.parent}: no such directory")
    if not toml_path.is_file():
        raise RecordingError(
            f"{toml_path}: no {MANIFEST_NAME} (not a fleet recording; for a folder of RINEX files, "
            f"`coplane recording init {root}` writes one)"
        )
    return toml_path.parent.resolve(), toml_path


def load_manifest(root: Path) -> Manifest:
    """Read and validate `<root>/fleet.toml` (or the .toml file given)."""
    root_dir, toml_path = _root_and_toml(root)
    try:
        with toml_path.open("rb") as f:
            doc = tomllib.load(f)
    except tomllib.TOMLDecodeError as exc:
        raise RecordingError(f"{toml_path}: not valid TOML ({exc})") from exc
    except UnicodeDecodeError as exc:  # tomllib decodes UTF-8 itself and lets this through
        raise RecordingError(f"{toml_path}: not UTF-8 text (byte {exc.start}): not a manifest") from exc
    except OSError as exc:
        raise RecordingError(f"{toml_path}: cannot read ({exc.strerror or exc})") from exc
    c = _Ctx(root_dir, toml_path)

    fmt = c.require(doc, "format", "format")
    if fmt != FORMAT:
        raise c.error("format", f"unknown format {fmt!r} (expected {FORMAT!r})")
    name = c.string(doc.get("name", root_dir.name), "name")

    time = c.table(c.require(doc, "time", "[time]"), "[time]")
    interval = c.number(c.require(time, "interval_s", "time.interval_s"), "time.interval_s", positive=True)

    nav = c.table(c.require(doc, "nav", "[nav]"), "[nav]")
    files = c.require(nav, "files", "nav.files")
    if isinstance(files, str):
        files = [files]
    if not isinstance(files, list) or not files:
        raise c.error("nav.files", "must be a non-empty list of paths")
    nav_files = tuple(c.path(f, f"nav.files[{i}]") for i, f in enumerate(files))

    base = None
    if "base" in doc:
        b = c.table(doc["base"], "[base]")
        base = BaseSpec(
            obs=c.path(c.require(b, "obs", "base.obs"), "base.obs"),
            position_ecef_m=c.xyz(
                c.require(b, "position_ecef_m", "base.position_ecef_m"), "base.position_ecef_m"
            ),
        )

    vehicles = _vehicles(c, c.require(doc, "vehicles", "[[vehicles]]"))

    uwb = None
    if "uwb" in doc:
        u = c.table(doc["uwb"], "[uwb]")
        uwb = UwbSpec(
            file=c.path(c.require(u, "file", "uwb.file"), "uwb.file"),
            sigma_m=c.number(u.get("sigma_m", 0.3), "uwb.sigma_m", positive=True),
            max_range_m=c.number(u.get("max_range_m", 500.0), "uwb.max_range_m", positive=True),
        )
    return Manifest(root_dir, name, interval, nav_files, vehicles, base, uwb)


def _vehicles(c: _Ctx, value: Any) -> tuple[VehicleSpec, ...]:
    if not isinstance(value, list) or not value:
        raise c.error("[[vehicles]]", "must be a non-empty array of tables")
    out: list[VehicleSpec] = []
    seen: set[str] = set()
    for i, v in enumerate(value):
        where = f"vehicles[{i}]"
        v = c.table(v, where)
        vid = c.string(c.require(v, "id", f"{where}.id"), f"{where}.id")
        if not is_vehicle_id(vid):
            raise c.error(f"{where}.id", f"invalid vehicle id {vid!r} (allowed: [A-Za-z0-9_-]{{1,32}})")
        if vid in seen:
            raise c.error(f"{where}.id", f"duplicate vehicle id {vid!r}")
        seen.add(vid)
        truth = c.path(v["truth"], f"{where}.truth") if "truth" in v else None
        out.append(
            VehicleSpec(
                id=vid,
                obs=c.path(c.require(v, "obs", f"{where}.obs"), f"{where}.obs"),
                antenna_height_m=c.number(
                    c.require(v, "antenna_height_m", f"{where}.antenna_height_m"), f"{where}.antenna_height_m"
                ),
                truth=truth,
            )
        )
    return tuple(out)


def _rel(m: Manifest, p: Path) -> str:
    root = Path(m.root).resolve()
    p = Path(p)
    try:
        return (p if p.is_absolute() else root / p).resolve().relative_to(root).as_posix()
    except ValueError:
        raise RecordingError(f"{p}: not inside the recording directory {m.root}") from None


def manifest_dict(manifest: Manifest) -> dict[str, Any]:
    """The fleet.toml content of a Manifest (paths relative to its root, in spec key order)."""
    m = manifest
    doc: dict[str, Any] = {
        "format": FORMAT,
        "name": m.name,
        "time": {"interval_s": m.interval_s},
        "nav": {"files": [_rel(m, p) for p in m.nav_files]},
    }
    if m.base is not None:
        doc["base"] = {"obs": _rel(m, m.base.obs), "position_ecef_m": list(m.base.position_ecef_m)}
    vehicles = []
    for v in m.vehicles:
        t: dict[str, Any] = {"id": v.id, "obs": _rel(m, v.obs), "antenna_height_m": v.antenna_height_m}
        if v.truth is not None:
            t["truth"] = _rel(m, v.truth)
        vehicles.append(t)
    doc["vehicles"] = vehicles
    if m.uwb is not None:
        doc["uwb"] = {"file": _rel(m, m.uwb.file), "sigma_m": m.uwb.sigma_m, "max_range_m": m.uwb.max_range_m}
    return doc


def write_manifest(manifest: Manifest) -> Path:
    """Write `<manifest.root>/fleet.toml` (deterministic; files it names need not exist yet)."""
    path = Path(manifest.root) / MANIFEST_NAME
    for v in manifest.vehicles:
        if not is_vehicle_id(v.id):
            raise RecordingError(f"vehicle id {v.id!r} is invalid (allowed: [A-Za-z0-9_-]{{1,32}})")
    ids = [v.id for v in manifest.vehicles]
    if len(set(ids)) != len(ids):
        raise RecordingError(f"duplicate vehicle ids in {ids}")
    text = tomli_w.dumps(manifest_dict(manifest))
    path.parent.mkdir(parents=True, exist_ok=True)
    # whole or not at all: a process killed while writing leaves the old manifest (or none), never
    # half of one (`coplane recording init --force` replaces a user's file)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    tmp.write_text(text, encoding="utf-8", newline="\n")
    os.replace(tmp, path)
    return path
