"""A real NTRIP caster for the live-path tests: pygnssutils' GNSSSocketServer in NTRIP mode (not a
mock), fed an RTCM 3 log at the pace it was recorded, as a base station's stream would be.

    python tests/support/ntrip_caster.py LOG PORT USER PASSWORD START_UNIX_S T0_WEEK T0_TOW

pygnssutils serves one mountpoint, named by its PYGPSMP constant (`MOUNTPOINT` here). Each epoch's
frames go out at `START_UNIX_S + (epoch - T0)`; a caster started late joins at the current epoch.
The log's ephemerides (before its first epoch) are not sent: pygnssutils' streamer loses the first
MSM after them (measured: the first epoch arrived with BeiDou only), and a base stream's
ephemerides are not what the agents need (the receivers broadcast their own).
"""

from __future__ import annotations

import subprocess
import sys
import threading
import time
from pathlib import Path

from pygnssutils.globals import PYGPSMP

from coplane.gtime import GpsTime
from coplane.recording.frames import Frame, rtcm_frames

MOUNTPOINT = PYGPSMP


class PacedLog:
    """A read()-able stream that releases the log's bytes epoch by epoch on the wall clock."""

    def __init__(self, path: Path, start: float, t0: tuple[int, float]) -> None:
        from receiver import epochs_of  # tests/support on sys.path (this file's folder)

        _, epochs = epochs_of(path, "rtcm3")
        t0g = GpsTime(*t0)
        self.items = [
            (start + (t - t0g), data) for t, data in epochs if start + (t - t0g) >= time.time() - 0.5
        ]
        if self.items:  # measured: pygnssutils' server loses the first message it relays, so
            # the first epoch's first frame goes out once before it (a repeat, if it arrives)
            first = next(f.raw for f in rtcm_frames(self.items[0][1]) if isinstance(f, Frame))
            self.items.insert(0, (self.items[0][0] - 0.5, first))
        self.buf = b""
        self.lock = threading.Lock()

    def read(self, n: int = 1) -> bytes:
        while len(self.buf) < n:
            if not self.items:
                time.sleep(0.2)  # the log is over: a base would go on, this one idles
                return b""
            due, data = self.items[0]
            wait = due - time.time()
            if wait > 0:
                time.sleep(min(wait, 0.05))
                continue
            self.items.pop(0)
            self.buf += data
        out, self.buf = self.buf[:n], self.buf[n:]
        return out

    def readline(self) -> bytes:  # GNSSStreamer may probe for NMEA; RTCM has no lines
        return self.read(1)


def start_caster(
    log: Path, port: int, user: str, password: str, start_unix_s: float, t0: GpsTime
) -> subprocess.Popen[bytes]:
    """The caster as its own process, listening on 127.0.0.1:`port` when this returns."""
    from coplane.fleet.launcher import wait_for_port

    p = subprocess.Popen(
        [
            sys.executable,
            __file__,
            str(log),
            str(port),
            user,
            password,
            f"{start_unix_s:.3f}",
            str(t0.week),
            repr(t0.tow),
        ],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    wait_for_port(port, 30)
    return p


def main(argv: list[str]) -> None:
    from pygnssutils import GNSSSocketServer

    log, port, user, password, start, week, tow = argv
    stream = PacedLog(Path(log), float(start), (int(week), float(tow)))
    server = GNSSSocketServer(
        stream=stream, hostip="127.0.0.1", outport=int(port), ntripmode=1,
        ntripuser=user, ntrippassword=password, maxclients=8, verbosity=0,
        protfilter=4, quitonerror=1, outformat=2,  # outformat 2: raw bytes, what a caster relays
    )  # fmt: skip
    server.run()
    while True:
        time.sleep(1)


if __name__ == "__main__":
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    main(sys.argv[1:])
