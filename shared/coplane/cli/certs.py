"""`coplane certs init DIR`: the local CA and one certificate per bus identity (coplane.bus.certs)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from coplane.cli.render import console
from coplane.errors import ConfigError

certs_app = typer.Typer(
    name="certs",
    help="Certificates for the secure bus (mutual TLS, access control by identity).",
    no_args_is_help=True,
)


def _owner(text: str | None) -> tuple[int, int] | None:
    if not text:
        return None
    try:
        uid, _, gid = text.partition(":")
        return int(uid), int(gid or uid)
    except ValueError as exc:
        raise ConfigError(f"--owner must be UID[:GID], got {text!r}") from exc


@certs_app.command("init")
def init(
    folder: Annotated[Path, typer.Argument(help="Certificates folder (created if missing).")],
    recording: Annotated[
        Path | None,
        typer.Option(
            help="A certificate for each vehicle of this recording (default without --vehicles: the bundled one)."
        ),
    ] = None,
    vehicles: Annotated[
        str, typer.Option(help="Vehicle ids, comma-separated (instead of --recording).")
    ] = "",
    dns: Annotated[str, typer.Option(help="More names the router is reached by, comma-separated.")] = "",
    owner: Annotated[
        str | None, typer.Option(help="UID[:GID] to own the identity keys (a root one-shot container).")
    ] = None,
    servers: Annotated[
        str,
        typer.Option(
            help="Ids of fusion servers sharing the fleet by region, comma-separated: each gets its own "
            "identity fusion-<id>, which may speak only for that server."
        ),
    ] = "",
) -> None:
    """Make a local CA and a key + certificate for the router, fusion, api, monitor and each vehicle.

    Never replaces an existing CA or certificate: run it again to add vehicles or servers.
    """
    from coplane.bus.certs import init_certs

    ids = [v.strip() for v in vehicles.split(",") if v.strip()]
    if recording is not None or not ids:
        from coplane.cli.options import recording_or_default
        from coplane.fleet import fleet_of

        ids += [v for v in fleet_of(recording_or_default(recording))[1] if v not in ids]
    extra = [d.strip() for d in dns.split(",") if d.strip()]
    server_list = [x.strip() for x in servers.split(",") if x.strip()]
    result = init_certs(folder, ids, extra, _owner(owner), servers=server_list)
    ca = "made a new CA" if result.ca_created else "kept the existing CA"
    console.print(f"{folder}: {ca}; created {len(result.created)}: {', '.join(result.created) or '-'}")
    if result.existing:
        console.print(f"already there (kept): {', '.join(result.existing)}")
