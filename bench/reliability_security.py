"""Security (issue 13): every (identity x key x operation) through a live router with mTLS and ACL.

    .venv/bin/python bench/reliability_security.py      # about 15 s

A Zenoh router with TLS listeners, client certificates required and coplane's access control
(coplane.bus.acl) runs as a separate Python process (`python -m coplane.bus.router`, exactly what
`coplane fleet` starts), for a 4-vehicle fleet. `coplane.bus.probe` then opens one session per
identity and tries every put, liveliness token, subscription and road-map area query (answering
one, asking one) on the fleet's keys, recording whether a legitimate listener (or the prober, for
subscriptions and queries) received it; and it tries to
connect without a certificate, with another CA's certificate and over plain TCP. `vehicle-u9` has a
certificate from the fleet's CA but is not one of the fleet's vehicles. `fusion-s1` and `fusion-s2`
are two fusion servers of a fleet with regions, each with its own identity (docs/bus.md): each may
speak only for itself.

Writes docs/reliability/security.md.
"""

from __future__ import annotations

import argparse
import datetime as dt
import os
import subprocess
import sys
import tempfile
import time
from collections import Counter
from pathlib import Path

from coplane.bus import BusSecurity
from coplane.bus.certs import init_certs
from coplane.bus.probe import Attempt, anonymous_tls_config, client_config, probe_access, probe_connections
from coplane.fleet import free_port, wait_for_port

REPO = Path(__file__).resolve().parents[1]
OUT = REPO / "docs" / "reliability" / "security.md"
FLEET = "bench"
VEHICLES = ["u1", "u2", "u3", "u4"]
SERVERS = ["s1", "s2"]  # fusion servers with identities of their own (regions)
IDENTITIES = ["vehicle-u1", "vehicle-u2", "vehicle-u9", "fusion", "fusion-s1", "fusion-s2", "api", "monitor"]


def run(work: Path) -> tuple[list[Attempt], list[Attempt], float]:
    certs = work / "certs"
    init_certs(certs, [*VEHICLES, "u9"], servers=SERVERS)  # the router finds the servers' in the folder
    (certs / "vehicle-u9.crt").rename(work / "vehicle-u9.crt")  # the router's ACL names the folder's
    (certs / "vehicle-u9.key").rename(work / "vehicle-u9.key")  # vehicles: u9 must not be one
    port = free_port()
    ep = f"tls/127.0.0.1:{port}"
    env = {**os.environ, "COPLANE_BUS_CERTS": str(certs), "COPLANE_BUS_IDENTITY": "router"}
    env.pop("COPLANE_BUS_INSECURE", None)
    router = subprocess.Popen(
        [sys.executable, "-m", "coplane.bus.router", "--listen", ep, "--fleet", FLEET],
        env=env,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    try:
        wait_for_port(port)
        for name in ("crt", "key"):  # the prober holds u9's certificate, the router never saw it
            (certs / f"vehicle-u9.{name}").write_bytes((work / f"vehicle-u9.{name}").read_bytes())
        os.chmod(certs / "vehicle-u9.key", 0o600)
        t0 = time.monotonic()
        access = probe_access(ep, certs, FLEET, IDENTITIES, VEHICLES)
        foreign = work / "foreign"
        init_certs(foreign, VEHICLES)
        connections = probe_connections(
            {
                "no client certificate": anonymous_tls_config(ep, certs / "ca.crt"),
                "fusion, signed by another CA": client_config(
                    ep, BusSecurity(certs=foreign, identity="fusion")
                ),
                "vehicle-u1, signed by another CA": client_config(
                    ep, BusSecurity(certs=foreign, identity="vehicle-u1")
                ),
                "plain TCP, no TLS": client_config(f"tcp/127.0.0.1:{port}", BusSecurity(insecure=True)),
            }
        )
        return access, connections, time.monotonic() - t0
    finally:
        router.terminate()
        router.wait(10)


def render(access: list[Attempt], connections: list[Attempt], seconds: float) -> str:
    leaked = [a for a in access + connections if a.delivered and not a.allowed]
    lost = [a for a in access if a.allowed and not a.delivered]
    by_op = Counter((a.operation, a.allowed) for a in access)
    lines = [
        "# Security: mutual TLS and access control, every identity x key x operation",
        "",
        "Regenerate: `.venv/bin/python bench/reliability_security.py` "
        f"(written {dt.date.today().isoformat()}; every number below comes from that run).",
        "",
        "A router with TLS listeners, client certificates required and coplane's access control "
        "(`coplane.bus.acl`, default deny) runs as its own process, as `coplane fleet` starts it; "
        f"the fleet is `{FLEET}` with vehicles {', '.join(VEHICLES)}. `coplane.bus.probe` tries every "
        "combination below through it and records whether a legitimate listener received it "
        "(for subscriptions: whether the subscriber received the legitimate publisher's sample; "
        "for `answer`: whether a fleet vehicle's area query for the road map got the identity's "
        "answer; for `ask`: whether the identity's query got a fusion server's answer). "
        "`vehicle-u9` holds a certificate from the fleet's CA but is not one of its vehicles. "
        f"{' and '.join(f'`fusion-{s}`' for s in SERVERS)} are fusion servers of a fleet with regions, "
        "each with its own identity, which may put only that server's solution, diagnostics and tile "
        "keys and declare only its liveliness token; `fusion` is the identity of a fleet's one "
        "server (or one that all servers share). "
        "Keys are relative to `coplane/v1/<fleet>/`. The same matrix, on a smaller fleet, is "
        "`tests/bus/test_access_control.py`.",
        "",
        f"**{len(access) + len(connections)} attempts, {sum(a.allowed for a in access)} authorised: "
        f"{len(leaked)} unauthorised delivered, {len(lost)} authorised lost** "
        f"(probe time {seconds:.1f} s).",
        "",
        "| operation | authorised: delivered | unauthorised: delivered |",
        "|---|---|---|",
    ]
    for op in ("put", "token", "subscribe", "liveliness-subscribe", "answer", "ask"):
        ok = [a for a in access if a.operation == op and a.allowed]
        bad = [a for a in access if a.operation == op and not a.allowed]
        lines.append(
            f"| {op} | {sum(a.delivered for a in ok)} of {by_op[(op, True)]} | "
            f"{sum(a.delivered for a in bad)} of {by_op[(op, False)]} |"
        )
    lines += [
        "",
        "## Connections without an acceptable certificate",
        "",
        "| client | expected | connected |",
        "|---|---|---|",
    ]
    lines += [f"| {a.identity} | refused | {'yes' if a.delivered else 'no'} |" for a in connections]
    lines += [
        "",
        "## Every attempt",
        "",
        "| identity | key | operation | expected | delivered |",
        "|---|---|---|---|---|",
    ]
    lines += [
        f"| {a.identity} | `{a.key}` | {a.operation} | {'allow' if a.allowed else 'deny'} | "
        f"{'yes' if a.delivered else 'no'}{'' if a.delivered == a.allowed else ' **MISMATCH**'} |"
        for a in access
    ]
    return "\n".join(lines) + "\n"


def main() -> int:
    argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    ).parse_args()
    with tempfile.TemporaryDirectory(prefix="coplane-security-") as tmp:
        access, connections, seconds = run(Path(tmp))
    OUT.parent.mkdir(parents=True, exist_ok=True)
    OUT.write_text(render(access, connections, seconds))
    bad = [a for a in access + connections if a.delivered != a.allowed]
    print(f"wrote {OUT}: {len(access) + len(connections)} attempts, {len(bad)} mismatches")
    return 1 if bad else 0


if __name__ == "__main__":
    raise SystemExit(main())
