"""NMEA 0183 output of the fleet's solutions: GGA + GST + RMC per vehicle over TCP (`coplane fleet
--nmea-port P`), for tools that read a receiver's NMEA (mapping apps, loggers, OpenCPN-style
viewers). Sentences are built and checksummed by pynmeagps.

NMEA has no vehicle field, so each vehicle gets its own port: the recording's vehicles in manifest
order on P, P+1, ... (printed at start). What the fields hold:
* time: UTC (GPS time minus the leap seconds, coplane.gtime.gpst_to_utc), centiseconds;
* lat/lon: 7 decimals of minutes (pynmeagps' high-precision mode, about 0.2 mm);
* GGA quality: 2 when the vehicle's epoch had the base's DGNSS corrections, 1 without them (a base
  that lags or drops out leaves epochs standalone), 6 (estimated) for an epoch the graph carried
  without a GNSS fix (`messages.fix_kind`, the rule of RTKLIB's Q in the .pos files); RMC's mode
  D / A / E alike; numSV: satellites used; HDOP: of the satellites the
  vehicle agent's own fix used (empty without one); age of differential corrections: the age of
  the base's corrections that fix used (empty standalone);
* GST: the fused solution's reported covariance as 1-sigma latitude / longitude / altitude errors
  (m) and its horizontal error ellipse (semi-major, semi-minor, orientation in degrees from true
  north), the fields receivers fill from their own covariance and tools such as ROS's NMEA driver
  read as the fix's uncertainty; the range-residual RMS is empty (the graph has no single one); no
  GST without a covariance;
* altitude: the ellipsoidal height with geoid separation 0 (coplane has no geoid model; alt + sep
  is the ellipsoidal height, as NMEA defines it);
* RMC speed (knots) and course: from this vehicle's previous solution (empty on its first).
Clients that read too slowly are dropped (counted), so a stuck client never holds the fleet back.
"""

from __future__ import annotations

import contextlib
import datetime as dt
import logging
import math
import socket
import threading
from collections import Counter
from collections.abc import Sequence

import numpy as np
from pynmeagps import GET, NMEAMessage

from coplane.errors import ConfigError
from coplane.geo import ecef_to_enu, ecef_to_geodetic, enu_rotation
from coplane.gtime import gpst_to_utc
from coplane.live.urls import MAX_PORT
from coplane.messages import FixKind, SolutionMessage, VehicleState, fix_kind
from coplane.steps.wire import gps_time

log = logging.getLogger("coplane.live.nmea_out")
KNOTS_PER_MPS = 3600.0 / 1852.0
SEND_TIMEOUT_S = 0.2
# GGA's quality and RMC's mode of each kind of fused solution (6 / E: estimated, dead reckoning)
GGA_QUALITY: dict[FixKind, int] = {"dgnss": 2, "single": 1, "dead-reckoned": 6}
RMC_MODE: dict[FixKind, str] = {"dgnss": "D", "single": "A", "dead-reckoned": "E"}


def _hemi(value: float, pos: str, neg: str) -> tuple[float, str]:
    return abs(value), pos if value >= 0.0 else neg


class NmeaFormatter:
    """Per vehicle: GGA + GST + RMC bytes for each solution (keeps the previous fix for speed/course)."""

    def __init__(self) -> None:
        self.previous: dict[str, tuple[float, np.ndarray]] = {}

    def sentences(self, sol: SolutionMessage) -> dict[str, bytes]:
        t = gps_time(sol.epoch)
        utc = gpst_to_utc(t)
        centi = round(utc.microsecond / 10000) * 10000  # NMEA prints centiseconds
        utc = utc.replace(microsecond=0) + dt.timedelta(microseconds=centi)
        out = {}
        for v in sol.vehicles:
            out[v.vehicle_id] = self._vehicle(v, t.seconds, utc)
        return out

    def _vehicle(self, v: VehicleState, t_s: float, utc: dt.datetime) -> bytes:
        p = np.array(v.position_ecef_m, dtype=float)
        lat_r, lon_r, h = (float(x) for x in ecef_to_geodetic(p))
        lat, ns = _hemi(math.degrees(lat_r), "N", "S")
        lon, ew = _hemi(math.degrees(lon_r), "E", "W")
        when = utc.time()
        kind = fix_kind(v.has_gnss_fix, v.dgnss_age_s)  # this epoch's corrections, not the fleet's
        gga = NMEAMessage(
            "GN", "GGA", GET, hpnmeamode=True, time=when, lat=lat, NS=ns, lon=lon, EW=ew,
            quality=GGA_QUALITY[kind], numSV=v.n_satellites, HDOP="" if v.hdop is None else round(v.hdop, 2),
            alt=round(h, 3), altUnit="M", sep=0.0, sepUnit="M",
            diffAge="" if v.dgnss_age_s is None else round(v.dgnss_age_s, 1), diffStation="",
        )  # fmt: skip
        spd: float | str = ""
        cog: float | str = ""
        prev = self.previous.get(v.vehicle_id)
        if prev is not None and t_s > prev[0]:
            enu = ecef_to_enu(p, prev[1])
            dt_s = t_s - prev[0]
            spd = round(math.hypot(enu[0], enu[1]) / dt_s * KNOTS_PER_MPS, 3)
            cog = round(math.degrees(math.atan2(enu[0], enu[1])) % 360.0, 2)
        self.previous[v.vehicle_id] = (t_s, p)
        gst = self._gst(v, p, lat_r, lon_r, when)
        rmc = NMEAMessage(
            "GN", "RMC", GET, hpnmeamode=True, time=when, status="A" if v.has_gnss_fix else "V",
            lat=lat, NS=ns, lon=lon, EW=ew, spd=spd, cog=cog, date=utc.date(), mv="", mvEW="",
            posMode=RMC_MODE[kind], navStatus="V",
        )  # fmt: skip
        return bytes(gga.serialize()) + gst + bytes(rmc.serialize())

    @staticmethod
    def _gst(v: VehicleState, p: np.ndarray, lat_r: float, lon_r: float, when: dt.time) -> bytes:
        """The GST sentence of the solution's covariance (b"" without one)."""
        if v.covariance_m2 is None:
            return b""
        r = enu_rotation(lat_r, lon_r)
        enu = r @ np.array(v.covariance_m2, dtype=float).reshape(3, 3) @ r.T
        vals, vecs = np.linalg.eigh(enu[:2, :2])  # ascending: the major axis is the last
        major = vecs[:, 1]
        orient = math.degrees(math.atan2(major[0], major[1])) % 180.0  # from north, clockwise
        sd = [math.sqrt(max(x, 0.0)) for x in (vals[1], vals[0], enu[1, 1], enu[0, 0], enu[2, 2])]
        gst = NMEAMessage(
            "GN", "GST", GET, time=when, rangeRms="", stdMajor=round(sd[0], 3), stdMinor=round(sd[1], 3),
            orient=round(orient, 1), stdLat=round(sd[2], 3), stdLong=round(sd[3], 3), stdAlt=round(sd[4], 3),
        )  # fmt: skip
        return bytes(gst.serialize())


class NmeaServer:
    """One listening TCP socket per vehicle; every connected client gets that vehicle's sentences."""

    def __init__(self, vehicles: Sequence[str], first_port: int, host: str = "127.0.0.1") -> None:
        self.formatter = NmeaFormatter()
        self.ports: dict[str, int] = {}
        self.listeners: dict[str, socket.socket] = {}
        self.clients: dict[str, list[socket.socket]] = {v: [] for v in vehicles}
        self.counts: Counter[str] = Counter()
        self.lock = threading.Lock()
        self.closed = threading.Event()
        if first_port and not 1 <= first_port <= MAX_PORT + 1 - len(vehicles):
            raise ConfigError(
                f"NMEA output: ports {first_port}..{first_port + len(vehicles) - 1} for {len(vehicles)}"
                f" vehicle(s) are not all within 1..{MAX_PORT}"
            )
        for i, vid in enumerate(vehicles):
            port = first_port + i if first_port else 0
            try:
                s = socket.create_server((host, port))
            except OSError as exc:  # e.g. the port is taken: say which, not a traceback
                self.close()
                raise ConfigError(
                    f"NMEA output for {vid}: cannot listen on {host}:{port} ({exc.strerror or exc})"
                ) from exc
            self.listeners[vid] = s
            self.ports[vid] = int(s.getsockname()[1])
        self.threads = [
            threading.Thread(target=self._accept, args=(vid, s), daemon=True, name=f"nmea-{vid}")
            for vid, s in self.listeners.items()
        ]
        for th in self.threads:
            th.start()

    def _accept(self, vid: str, listener: socket.socket) -> None:
        while not self.closed.is_set():
            try:
                conn, _ = listener.accept()
            except OSError:
                return  # closed
            conn.settimeout(SEND_TIMEOUT_S)
            with self.lock:
                self.clients[vid].append(conn)
                self.counts["connections"] += 1

    def publish(self, sol: SolutionMessage) -> None:
        """Send one solution's sentences to every client of each vehicle in it (never raises)."""
        try:
            lines = self.formatter.sentences(sol)
        except Exception:
            self.counts["format-errors"] += 1
            log.exception("NMEA sentences not built", extra={"seq": sol.seq})
            return
        with self.lock:
            for vid, data in lines.items():
                for c in list(self.clients.get(vid, [])):
                    try:
                        c.sendall(data)
                        self.counts["sentences"] += 2
                    except OSError:  # gone, or too slow to read: drop it
                        self.clients[vid].remove(c)
                        self.counts["dropped-clients"] += 1
                        with contextlib.suppress(OSError):
                            c.close()

    def close(self) -> None:
        self.closed.set()
        for s in self.listeners.values():
            with contextlib.suppress(OSError):
                s.close()
        with self.lock:
            for cs in self.clients.values():
                for c in cs:
                    with contextlib.suppress(OSError):
                        c.close()
                cs.clear()
