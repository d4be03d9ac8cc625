"""A corpus of corrupted fleet recordings: one clean simulated recording, one defect each.

Used by tests/recording/test_corrupt_corpus.py (every command must survive each one: no traceback,
bounded time and memory, and either a non-zero exit naming the file or a printed problem count)
and by bench/reliability_recordings.py, which writes docs/reliability/recordings.md.

Each defect is what a user's file system, receiver or conversion tool really produces: cut files,
binary junk, a corrupt epoch year, NaN and 1e308 values, traversal paths, an empty nav file.
"""

from __future__ import annotations

import re
import shutil
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

Mutate = Callable[[Path], None]


@dataclass(frozen=True)
class Defect:
    name: str
    what: str
    mutate: Mutate


def _edit(path: Path, fn: Callable[[str], str]) -> None:
    path.write_text(fn(path.read_text()))


def _obs(root: Path) -> Path:
    return root / "vehicles" / "u1.obs"


def _epoch_lines(text: str) -> list[int]:
    lines = text.splitlines(keepends=True)
    return [i for i, ln in enumerate(lines) if ln.startswith(">")]


def _replace_epoch_year(root: Path, index: int, year: str) -> None:
    def fn(text: str) -> str:
        lines = text.splitlines(keepends=True)
        i = _epoch_lines(text)[index]
        lines[i] = lines[i][:2] + year + lines[i][6:]
        return "".join(lines)

    _edit(_obs(root), fn)


def _cut(root: Path, fraction: float) -> None:
    p = _obs(root)
    data = p.read_bytes()
    p.write_bytes(data[: int(len(data) * fraction)])


def _insert_bytes(root: Path, blob: bytes) -> None:
    p = _obs(root)
    data = p.read_bytes()
    mid = data.index(b"\n", len(data) // 2) + 1
    p.write_bytes(data[:mid] + blob + data[mid:])


def _sub_field(root: Path, pattern: str, repl: str, count: int = 3) -> None:
    _edit(_obs(root), lambda t: re.sub(pattern, repl, t, count=count, flags=re.M))


def _uwb_value(root: Path, value: str) -> None:
    def fn(text: str) -> str:
        lines = text.splitlines(keepends=True)
        for i in (2, 5, 8):
            if i < len(lines):
                parts = lines[i].rstrip("\n").split(",")
                parts[-1] = value
                lines[i] = ",".join(parts) + "\n"
        return "".join(lines)

    _edit(root / "uwb.csv", fn)


def _nav_header_only(root: Path) -> None:
    p = root / "nav" / "brdc.rnx"
    text = p.read_text()
    end = text.index("END OF HEADER")
    p.write_text(text[: text.index("\n", end) + 1])


def _nav_nan(root: Path) -> None:
    _edit(root / "nav" / "brdc.rnx", lambda t: re.sub(r"-?\d\.\d{12}E[+-]\d\d", "NaN", t))


def _nav_week_earlier(root: Path) -> None:
    """Every record's toc and week number a week earlier (GPS week 2320, BDT week 964)."""

    def fn(text: str) -> str:
        text = text.replace(" 2024 06 24 ", " 2024 06 17 ")
        return text.replace("2.320000000000E+03", "2.319000000000E+03").replace(
            "9.640000000000E+02", "9.630000000000E+02"
        )

    _edit(root / "nav" / "brdc.rnx", fn)


def _manifest(root: Path, fn: Callable[[str], str]) -> None:
    _edit(root / "fleet.toml", fn)


DEFECTS: tuple[Defect, ...] = (
    Defect("obs-year-2094", "one epoch's year 2024 -> 2094", lambda r: _replace_epoch_year(r, 5, "2094")),
    Defect("obs-year-1980", "one epoch's year 2024 -> 1980", lambda r: _replace_epoch_year(r, 5, "1980")),
    Defect("obs-last-epoch-2094", "the last epoch's year -> 2094", lambda r: _replace_epoch_year(r, -1, "2094")),
    Defect("obs-cut-half", "u1.obs cut mid-line at half its size", lambda r: _cut(r, 0.5)),
    Defect("obs-cut-header", "u1.obs cut inside its header", lambda r: _cut(r, 0.02)),
    Defect("obs-empty", "u1.obs is empty", lambda r: _obs(r).write_bytes(b"")),
    Defect("obs-binary-junk", "4 KiB of binary junk mid-file", lambda r: _insert_bytes(r, bytes(range(256)) * 16)),
    Defect("obs-nul-bytes", "NUL bytes mid-file", lambda r: _insert_bytes(r, b"\x00" * 1000 + b"\n")),
    Defect("obs-long-line", "one 8 MB line mid-file", lambda r: _insert_bytes(r, b"9" * 8_000_000 + b"\n")),
    Defect("obs-not-utf8", "Latin-1 bytes in a record", lambda r: _insert_bytes(r, b"G05 \xe9\xe8\xff\n")),
    Defect("obs-nan", "NaN pseudoranges", lambda r: _sub_field(r, r"^(C\d\d|G\d\d)  \d{8}\.\d{3}", r"\1  NaN         ")),
    Defect("obs-1e308", "1e308 pseudoranges", lambda r: _sub_field(r, r"^(C\d\d|G\d\d)  \d{8}\.\d{3}", r"\1  1e308       ")),
    Defect("obs-not-rinex", "u1.obs replaced by a CSV file", lambda r: _obs(r).write_text("a,b,c\n1,2,3\n")),
    Defect("nav-header-only", "nav file without records", _nav_header_only),
    Defect("nav-nan", "every nav number NaN", _nav_nan),
    Defect("nav-empty", "nav file empty", lambda r: (r / "nav" / "brdc.rnx").write_bytes(b"")),
    Defect("nav-other-week", "ephemerides of a week earlier: nothing can be positioned", _nav_week_earlier),
    Defect("nav-missing", "nav file deleted", lambda r: (r / "nav" / "brdc.rnx").unlink()),
    Defect("uwb-nan", "NaN ranges", lambda r: _uwb_value(r, "nan")),
    Defect("uwb-negative", "negative ranges", lambda r: _uwb_value(r, "-12.5")),
    Defect("uwb-1e308", "1e308 ranges", lambda r: _uwb_value(r, "1e308")),
    Defect("uwb-bad-header", "uwb.csv header garbled", lambda r: _edit(r / "uwb.csv", lambda t: "x,y\n" + t.split("\n", 1)[1])),
    Defect("truth-junk", "truth rows with junk", lambda r: _edit(r / "truth" / "u1.csv", lambda t: t + "junk,,,\n2320,abc,1,2,3\n")),
    Defect("manifest-bad-toml", "fleet.toml syntax error", lambda r: _manifest(r, lambda t: t.replace("]", "", 1))),
    Defect("manifest-traversal", "a vehicle's obs path escapes the recording", lambda r: _manifest(r, lambda t: t.replace('"vehicles/u1.obs"', '"../../../../etc/passwd"'))),
    Defect("manifest-interval-zero", "interval_s = 0", lambda r: _manifest(r, lambda t: re.sub(r"interval_s = [\d.]+", "interval_s = 0.0", t))),
    Defect("manifest-binary", "fleet.toml is binary junk", lambda r: (r / "fleet.toml").write_bytes(bytes(range(256)))),
)  # fmt: skip


def make_corpus(clean: Path, out: Path) -> dict[str, Path]:
    """A copy of `clean` per defect under `out`, each with its defect applied; name -> directory."""
    made: dict[str, Path] = {}
    for d in DEFECTS:
        target = out / d.name
        if target.exists():
            shutil.rmtree(target)
        shutil.copytree(clean, target)
        d.mutate(target)
        made[d.name] = target
    return made


@dataclass(frozen=True)
class CorpusRun:
    """One command on one corrupted recording, as a user would see it."""

    defect: str
    command: str
    exit_code: int
    wall_s: float
    peak_rss_mb: float
    traceback: bool
    names_file: bool  # the error output names a file of the recording
    problem_count: bool  # the output prints "N input problems"
    last_line: str

    @property
    def ok(self) -> bool:
        """The acceptance rule: no traceback, and either a non-zero exit that names the file or a
        printed problem count."""
        named = self.exit_code != 0 and self.names_file
        return not self.traceback and (named or self.problem_count)


def command_args(command: str, recording: Path, out: Path, strict: bool = False) -> list[str]:
    """The coplane command line for `command` ("eval" or "spp") on `recording`, output under `out`."""
    flags = ["--strict"] if strict else []
    if command == "eval":
        return ["eval", str(recording), "--methods", "non-cp", "--jobs", "1", "--out", str(out), *flags]
    if command == "spp":
        return ["spp", str(recording), "--out", str(out / "rover.pos"), *flags]
    raise ValueError(f"unknown command {command!r}")


# fork the command, wait for it, write "<peak RSS kB> <exit code>" to the fd in argv[1]
_WRAPPER = (
    "import os, sys\n"
    "fd = int(sys.argv[1])\n"
    "pid = os.fork()\n"
    "if pid == 0:\n"
    "    os.close(fd)\n"
    "    os.execvp(sys.argv[2], sys.argv[2:])\n"
    "_, status, usage = os.wait4(pid, 0)\n"
    "os.write(fd, f'{usage.ru_maxrss} {os.waitstatus_to_exitcode(status)}'.encode())\n"
)


def run_one(
    coplane: str,
    command: str,
    defect: str,
    recording: Path,
    out: Path,
    strict: bool = False,
    timeout: float = 120.0,
) -> CorpusRun:
    """Run the command in a child process; wall time, and the child's peak RSS from wait4.

    The command is started by a small Python wrapper that forks it and reports its `wait4` usage on
    a pipe: a child forked straight from the test process would count the test process's own
    resident pages (inherited at fork) in its peak RSS, so a test session that grew would make
    every command look large."""
    import os
    import signal
    import subprocess
    import sys
    import tempfile
    import threading
    import time

    args = [coplane, *command_args(command, recording, out, strict)]
    env = {**os.environ, "COLUMNS": "200", "NO_COLOR": "1"}
    r, w = os.pipe()
    with tempfile.TemporaryFile() as log:
        t0 = time.monotonic()
        p = subprocess.Popen(
            [sys.executable, "-c", _WRAPPER, str(w), *args],
            stdout=log,
            stderr=subprocess.STDOUT,
            env=env,
            pass_fds=(w,),
            start_new_session=True,
        )
        os.close(w)
        killer = threading.Timer(timeout, lambda: os.killpg(p.pid, signal.SIGKILL))
        killer.start()
        try:
            with os.fdopen(r) as pipe:
                reported = pipe.read().split()
            p.wait()
        finally:
            killer.cancel()
        maxrss_kb, code = (int(reported[0]), int(reported[1])) if len(reported) == 2 else (0, -9)
        p.returncode = code
        wall = time.monotonic() - t0
        log.seek(0)
        text = log.read().decode(errors="replace")
    files = [str(f.relative_to(recording)) for f in recording.rglob("*") if f.is_file()] + ["fleet.toml"]
    return CorpusRun(
        defect=defect,
        command=command,
        exit_code=p.returncode,
        wall_s=wall,
        peak_rss_mb=maxrss_kb / 1024,
        traceback="Traceback (most recent call last)" in text,
        names_file=any(name in text for name in files) or str(recording) in text,
        problem_count=re.search(r"\d+ input problems", text) is not None,
        last_line=(text.strip().splitlines() or [""])[-1][:160],
    )
