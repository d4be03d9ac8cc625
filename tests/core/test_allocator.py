"""The services coplane starts run on jemalloc where the machine has it (coplane/allocator.py),
chosen by COPLANE_ALLOCATOR, which is checked like any other setting."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

import coplane.allocator as allocator
import coplane.fleet.launcher as launcher
from coplane.allocator import allocator_env, allocator_library, loaded_allocator
from coplane.errors import ConfigError


def test_auto_is_jemalloc_when_found(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(allocator, "_find_jemalloc", lambda: "libjemalloc.so.2")
    assert allocator_library({}) == "libjemalloc.so.2"
    assert allocator_library({"COPLANE_ALLOCATOR": " auto "}) == "libjemalloc.so.2"
    assert allocator_env({}) == {"LD_PRELOAD": "libjemalloc.so.2"}
    # the allocator goes first; what the user preloads stays, and nothing is added twice
    assert allocator_env({"LD_PRELOAD": "libfoo.so"}) == {"LD_PRELOAD": "libjemalloc.so.2:libfoo.so"}
    assert allocator_env({"LD_PRELOAD": "libfoo.so libjemalloc.so.2"}) == {}
    assert allocator_env({"LD_PRELOAD": "/usr/lib/x86_64-linux-gnu/libjemalloc.so.2"}) == {}
    monkeypatch.setattr(allocator, "_find_jemalloc", lambda: None)
    assert allocator_library({}) is None and allocator_env({}) == {}


def test_system_and_explicit_library(tmp_path: Path) -> None:
    assert allocator_library({"COPLANE_ALLOCATOR": "system"}) is None
    assert allocator_env({"COPLANE_ALLOCATOR": "system", "LD_PRELOAD": "libfoo.so"}) == {}
    lib = tmp_path / "libmyalloc.so"
    lib.write_bytes(b"")
    assert allocator_library({"COPLANE_ALLOCATOR": str(lib)}) == str(lib)


@pytest.mark.parametrize("bad", ["jemalloc", "/nonexistent/libjemalloc.so.2", "System"])
def test_a_bad_setting_names_the_variable(bad: str) -> None:
    """A user's error (ConfigError: `coplane fleet` prints it and exits 2, no traceback)."""
    with pytest.raises(ConfigError, match="COPLANE_ALLOCATOR"):
        allocator_library({"COPLANE_ALLOCATOR": bad})


def test_the_launcher_preloads_it(monkeypatch: pytest.MonkeyPatch) -> None:
    """Every service the fleet starts gets the allocator; an env the caller passes still wins."""
    monkeypatch.setattr(allocator, "_find_jemalloc", lambda: "libjemalloc.so.2")
    monkeypatch.delenv("COPLANE_ALLOCATOR", raising=False)
    monkeypatch.delenv("LD_PRELOAD", raising=False)
    seen: list[dict[str, str]] = []

    class FakePopen:
        pid = 0

        def __init__(self, *args: Any, env: dict[str, str], **kwargs: Any) -> None:
            seen.append(env)

    monkeypatch.setattr(launcher.subprocess, "Popen", FakePopen)
    procs = launcher.FleetProcesses()
    procs.start(launcher.ServiceSpec("fusion", launcher.FUSION_MODULE))
    procs.start(launcher.ServiceSpec("api", launcher.API_MODULE), env={"LD_PRELOAD": ""})
    assert seen[0]["LD_PRELOAD"] == "libjemalloc.so.2"
    assert seen[1]["LD_PRELOAD"] == ""


def test_a_child_runs_on_it() -> None:
    """With jemalloc installed (scripts/setup.sh installs it), a child started with the
    environment really runs on it, and this process can tell."""
    env = allocator_env({})
    if not env:
        pytest.skip("no jemalloc on this machine (Debian: libjemalloc2)")
    code = "from coplane.allocator import loaded_allocator; print(loaded_allocator())"
    out = subprocess.run(
        [sys.executable, "-c", code], env={**os.environ, **env}, capture_output=True, text=True
    )
    assert out.stdout.strip() == "jemalloc", out.stderr
    assert loaded_allocator(Path("/nonexistent/maps")) == "unknown"


def test_the_image_preloads_it() -> None:
    """docker-compose's services run on the image's jemalloc, as `coplane fleet`'s do."""
    dockerfile = (Path(__file__).resolve().parents[2] / "Dockerfile").read_text()
    assert "libjemalloc2" in dockerfile and "ENV LD_PRELOAD=libjemalloc.so.2" in dockerfile


# a child just spawned may be between its exec and the dynamic linker's mapping of the preloaded
# library (a window that a loaded CI machine widens): each is looked at until its interpreter is
# mapped, and only then judged
POOL = """
import dataclasses, multiprocessing as mp, time
from coplane.fgo.config import FgoConfig
from coplane.parallel import smoothers_for
pool = smoothers_for(dataclasses.replace(FgoConfig(), solver="isam2-fixed-lag"), 2)
def allocator(pid):
    for _ in range(600):
        maps = open(f"/proc/{pid}/maps").read()
        if "jemalloc" in maps or "libpython" in maps or "_multiprocessing" in maps:
            return "jemalloc" if "jemalloc" in maps else "other"
        time.sleep(0.05)
    return "not-started"
print(" ".join(allocator(k.pid) for k in mp.active_children()))
pool.close()
"""


def test_a_servers_cluster_processes_inherit_it() -> None:
    """A fusion server's cluster processes (`--cluster_workers`) are spawned with its environment,
    so they run on its allocator too (docs/scale.md)."""
    env = allocator_env({})
    if not env:
        pytest.skip("no jemalloc on this machine (Debian: libjemalloc2)")
    out = subprocess.run(
        [sys.executable, "-c", POOL], env={**os.environ, **env}, capture_output=True, text=True, timeout=120
    )
    assert out.returncode == 0, out.stderr
    assert out.stdout.split() == ["jemalloc"], out.stdout
