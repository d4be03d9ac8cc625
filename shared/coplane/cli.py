"""The `coplane` command. Each subcommand is a thin wrapper over library functions."""

from __future__ import annotations

import typer

app = typer.Typer(
    name="coplane",
    help="Plane-constraint-aided cooperative positioning for vehicle fleets.",
    no_args_is_help=True,
    add_completion=False,
)


@app.callback()
def main() -> None:
    """coplane: replay fleet recordings, run SPP and the cooperative estimators, serve results."""


@app.command()
def version() -> None:
    """Print the coplane version."""
    from coplane import __version__

    typer.echo(__version__)


if __name__ == "__main__":
    app()
