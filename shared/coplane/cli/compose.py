"""`coplane compose`: write docker-compose.yml from the fleet launcher's service list."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from coplane.cli.render import console
from coplane.typing import Pace


def compose(
    out: Annotated[Path, typer.Option(help="Where to write the compose file.")] = Path("docker-compose.yml"),
    method: Annotated[str, typer.Option(help="Estimator method.")] = "pc",
    pace: Annotated[Pace, typer.Option(help="lockstep or realtime.")] = "realtime",
    router_config: Annotated[
        Path | None,
        typer.Option(
            help="Where to write the router's config; default deploy/zenoh/router.json5 beside --out."
        ),
    ] = None,
    servers: Annotated[
        int, typer.Option(min=1, help="Fusion servers sharing the fleet by region (docs/scale.md).")
    ] = 1,
    routers: Annotated[
        int,
        typer.Option(min=1, help="Zenoh routers in a mesh; the further ones connect to the first."),
    ] = 1,
    cluster_workers: Annotated[
        int,
        typer.Option(
            "--cluster-workers", min=1, max=64, help="Processes per fusion server solving its clusters."
        ),
    ] = 1,
) -> None:
    """Write docker-compose.yml (and the routers' TLS + access-control configs) for the bundled
    recording from the launcher's own service list. The committed file is the default (one router,
    one server); e.g. `coplane compose --servers 2 --routers 2 --out docker-compose.scale.yml`."""
    from coplane.fleet import write_compose

    result = write_compose(
        out, method, pace, router_config, servers=servers, routers=routers, cluster_workers=cluster_workers
    )
    console.print(f"wrote {result.path} ({result.services} services) and {result.router_config}")
