"""`coplane agent`: one vehicle agent in the foreground, on live streams or replaying a recording.

The same process `coplane fleet` and docker-compose start (`python -m coplane.vehicle_agent`),
with the options a fleet operator types: where the receiver, the base and the UWB radio are
(docs/live.md), and how the agent joins the bus (secure by default: the vehicle's certificate
from the certificates folder; `--insecure` is the explicit, warned-about exception).
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from coplane.cli.options import recording_or_default
from coplane.cli.render import err_console
from coplane.typing import Pace


def agent(
    vehicle_id: Annotated[str, typer.Option("--vehicle-id", help="This vehicle's id in fleet.toml.")],
    recording: Annotated[
        Path | None,
        typer.Option(
            help="fleet.toml's folder: the fleet's vehicles, base and UWB settings; default: bundled."
        ),
    ] = None,
    gnss: Annotated[
        str | None,
        typer.Option(
            help="Receiver stream, e.g. ubx+tcp://HOST:PORT or rtcm3+serial:///dev/ttyACM0?baud=115200; "
            "default: replay the recording's file."
        ),
    ] = None,
    base: Annotated[
        str | None, typer.Option(help="Base corrections, e.g. ntrip://user:pass@HOST:2101/MOUNT.")
    ] = None,
    uwb: Annotated[str | None, typer.Option(help="UWB ranges, e.g. udp://:5600.")] = None,
    method: Annotated[str, typer.Option(help="Estimator method (the fusion server's).")] = "pc",
    pace: Annotated[Pace, typer.Option(help="realtime (live receivers) or lockstep (logs).")] = "realtime",
    connect: Annotated[str, typer.Option(help="Zenoh router endpoint.")] = "tls/127.0.0.1:7447",
    fleet: Annotated[
        str | None, typer.Option(help="Bus fleet id; default: from the recording's name.")
    ] = None,
    certs: Annotated[
        Path | None, typer.Option(help="Certificates folder; default: ~/.local/state/coplane/certs.")
    ] = None,
    insecure: Annotated[bool, typer.Option(help="Plain TCP, no certificates (debugging only).")] = False,
    max_correction_age: Annotated[
        float, typer.Option(help="Drop base corrections older than this many seconds.")
    ] = 30.0,
    nmea_port: Annotated[
        int | None,
        typer.Option(
            "--nmea-port",
            help="Serve this vehicle's fused solutions as NMEA 0183 GGA + GST + RMC over TCP on 127.0.0.1 at"
            " this port (0: any free port; logged at start).",
        ),
    ] = None,
) -> None:
    """Run one vehicle agent until its receiver stream ends or Ctrl-C."""
    from coplane.bus.security import BusSecurity, use_security, vehicle_identity
    from coplane.fleet.run import default_certs_dir
    from coplane.runtime import setup_logging, stop_event
    from coplane.vehicle_agent.agent import VehicleAgent
    from coplane.vehicle_agent.settings import AgentSettings

    if insecure:
        err_console.print("[bold red]WARNING: --insecure: plain TCP, no authentication[/bold red]")
        connect = connect.replace("tls/", "tcp/", 1)
    security = BusSecurity(
        certs=None if insecure else (certs or default_certs_dir()),
        identity=vehicle_identity(vehicle_id),
        insecure=insecure,
    )
    if security.secure:
        security.files()  # a missing certificate is a ConfigError naming the file, before anything starts
    settings = AgentSettings(
        recording=recording_or_default(recording),
        vehicle_id=vehicle_id,
        gnss=gnss,
        base=base,
        uwb=uwb,
        method=method,
        pace=pace,  # type: ignore[arg-type]
        connect=[connect],
        fleet=fleet,
        max_correction_age_s=max_correction_age,
        nmea_port=nmea_port,
    )
    setup_logging(f"agent-{vehicle_id}", settings.log_level)
    stop = stop_event()
    with use_security(security):
        agent_ = VehicleAgent(settings, stop)
        published = agent_.run()
    err_console.print(f"{vehicle_id}: {published} node messages published")
