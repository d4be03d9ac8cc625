"""The layering of docs/architecture.md, enforced: imports go one way, from the core out to the shells.

Every `import` and `from ... import` in the library and the services (including imports inside
functions, which are still dependencies) is checked against the layer table below: a package may
import only packages of a lower layer, or itself. Two packages on the same layer (e.g. `fgo` and
`baselines`) must not import each other. A new top-level package must be added to the table.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]

# layer of each top-level name under `coplane` (the services map to coplane.<name> in pyproject)
LAYERS: dict[str, int] = {
    # core: no dependency on anything else in coplane
    "typing": 0,
    "errors": 0,
    "ids": 0,
    "components": 0,  # union-find for clusters of ranged vehicles
    "blas_threads": 0,  # one BLAS thread per process, applied by coplane/__init__.py
    "gtime": 1,
    "allocator": 1,  # jemalloc for the processes coplane starts (fleet/launcher.py); errors only
    "geo": 1,
    "numeric": 1,  # numpy's norms without their wrappers' overhead, for per-epoch loops
    # data and models
    "recording": 2,
    "gnss": 3,
    "plane": 4,
    "sim": 4,
    # estimation
    "estimation": 5,
    "roadmap": 5,  # the road-surface map: core (geo, gtime, errors, typing, ids) and plane/ only
    "fgo": 6,
    "baselines": 6,
    "regions": 6,  # fleet regions and their ownership over fusion servers: roadmap.grid only
    "methods": 7,
    # the per-epoch steps and their wire models
    "messages": 8,
    "steps": 9,
    "replay": 10,
    "evaluate": 11,
    # shells
    "runtime": 12,
    "store": 12,  # the solution log (SQLite) the services and the fleet collector keep
    "live": 12,  # live receiver streams, NTRIP and UWB input (transports and stream decoding)
    "parallel": 12,  # a fusion server's cluster smoothers on child processes (injected into fgo)
    "bus": 13,
    "fleet": 14,
    "vehicle_agent": 15,
    "fusion_server": 15,
    "api": 15,
    "cli": 16,
}
SOURCES = {
    ROOT / "shared" / "coplane": None,  # None: the first path part is the package
    ROOT / "services" / "vehicle_agent": "vehicle_agent",
    ROOT / "services" / "fusion_server": "fusion_server",
    ROOT / "services" / "api": "api",
}


def _package_of(path: Path) -> str | None:
    for base, name in SOURCES.items():
        if base in path.parents:
            if name is not None:
                return name
            rel = path.relative_to(base)
            return rel.parts[0].removesuffix(".py") if rel.parts[0] != "__init__.py" else None
    return None


def _imports(path: Path) -> list[tuple[int, str]]:
    """(line, top-level coplane name) of every import of a coplane module in `path`."""
    out: list[tuple[int, str]] = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        names: list[str] = []
        if isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names = [node.module] + [
                f"{node.module}.{a.name}" for a in node.names if node.module == "coplane"
            ]
        for n in names:
            parts = n.split(".")
            if parts[0] == "coplane" and len(parts) > 1:
                out.append((node.lineno, parts[1]))
    return out


def _sources() -> list[Path]:
    return sorted(p for base in SOURCES for p in base.rglob("*.py"))


def test_every_package_has_a_layer() -> None:
    packages = {_package_of(p) for p in _sources()} - {None, "__main__"}
    assert packages <= set(LAYERS), f"add to LAYERS: {sorted(packages - set(LAYERS))}"


def test_every_library_package_is_installed() -> None:
    """pyproject lists packages by hand: a folder missing there works in the editable install the
    tests use and is absent from a wheel or the Docker image."""
    import tomllib

    listed = set(tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["packages"])
    lib = ROOT / "shared" / "coplane"
    folders = {
        "coplane." + ".".join(d.relative_to(lib).parts)
        for d in lib.rglob("*")
        if d.is_dir() and (d / "__init__.py").exists()
    }
    assert folders <= listed, f"add to [tool.setuptools] packages: {sorted(folders - listed)}"


def test_imports_go_one_way() -> None:
    bad: list[str] = []
    for path in _sources():
        pkg = _package_of(path)
        if pkg is None or pkg == "__main__":
            continue
        for line, target in _imports(path):
            if target == pkg or target == "__version__":
                continue
            if target not in LAYERS:
                bad.append(f"{path.relative_to(ROOT)}:{line}: imports unknown coplane.{target}")
            elif LAYERS[target] >= LAYERS[pkg]:
                bad.append(
                    f"{path.relative_to(ROOT)}:{line}: {pkg} (layer {LAYERS[pkg]}) imports "
                    f"{target} (layer {LAYERS[target]})"
                )
    assert not bad, "upward or sideways imports:\n" + "\n".join(bad)


@pytest.mark.parametrize("limit", [400])
def test_modules_are_small_or_say_why(limit: int) -> None:
    """A module over the limit must say in its docstring why it stays one file."""
    long = []
    for path in _sources():
        text = path.read_text()
        if text.count("\n") > limit:
            doc = ast.get_docstring(ast.parse(text)) or ""
            if "one file" not in doc.lower():
                long.append(f"{path.relative_to(ROOT)}: {text.count(chr(10))} lines")
    assert not long, "split these or say in the docstring why they are one file:\n" + "\n".join(long)
