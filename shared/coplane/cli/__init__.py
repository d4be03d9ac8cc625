"""The `coplane` command: one module per subcommand, registered here on one typer app.

Each command parses its options, calls a library function and renders what it returns. A
`CoplaneError` from any of them is caught here, once: the user sees its message and the process
exits with its `exit_code`. So does an OS error on a path (no such folder, no permission, a full
disk): the path and the reason are printed; and a service's settings made invalid by an option or
a COPLANE_* variable: the field and the reason. Any other exception is a bug and keeps its
traceback.

Ctrl-C (SIGINT) and SIGTERM end any command cleanly, through the `with` blocks on the way out
(worker processes joined, files closed), with exit code 130 or 143. `coplane fleet` handles both
signals itself, to stop its processes together (coplane.cli.fleet).
"""

from __future__ import annotations

import errno
import logging
import signal
import threading
from typing import Annotated, Any

import typer
from rich.markup import escape
from typer.core import TyperGroup

from coplane.cli.agent import agent
from coplane.cli.certs import certs_app
from coplane.cli.compose import compose
from coplane.cli.convert import convert
from coplane.cli.eval import eval_
from coplane.cli.fleet import fleet
from coplane.cli.loadgen import loadgen
from coplane.cli.map import map_app
from coplane.cli.recording import recording_app
from coplane.cli.render import err_console
from coplane.cli.simulate import simulate_command
from coplane.cli.spp import spp
from coplane.errors import CoplaneError


class _Terminated(BaseException):
    """SIGTERM, raised in the main thread like KeyboardInterrupt so `with` blocks unwind."""


def _raise_terminated(_signum: int, _frame: Any) -> None:
    raise _Terminated


# The OS errors that name a path the user can fix; any other OSError keeps its traceback.
_PATH_ERRORS = frozenset(
    {
        errno.ENOENT, errno.ENOTDIR, errno.EISDIR, errno.EACCES, errno.EPERM, errno.EROFS,
        errno.ENOSPC, errno.EDQUOT, errno.EEXIST, errno.ENAMETOOLONG, errno.ELOOP,
    }
)  # fmt: skip


def _path_error(exc: OSError) -> str:
    """'/proc/x: No such file or directory'; both paths of a failed rename or copy."""
    where = f"{exc.filename} -> {exc.filename2}" if exc.filename2 else str(exc.filename)
    return f"{where}: {exc.strerror or exc}"


def _settings_error(exc: ValueError) -> str | None:
    """A service's settings (pydantic-settings) that an option or a COPLANE_* variable made
    invalid, as one line per field: 'AgentSettings: max_correction_age_s: Input should be greater
    than 0 (got -5.0)'. None for any other ValueError, which keeps its traceback. Told apart by
    its interface rather than by importing pydantic, which the command line otherwise loads lazily."""
    errors = getattr(exc, "errors", None)
    title = getattr(exc, "title", None)
    if type(exc).__name__ != "ValidationError" or not callable(errors) or title is None:
        return None
    lines = []
    for e in errors():
        where = ".".join(str(p) for p in e.get("loc", ())) or "(settings)"
        lines.append(f"{title}: {where}: {e.get('msg', 'invalid')} (got {e.get('input')!r})")
    return "; ".join(lines)


class _CoplaneGroup(TyperGroup):
    """The command group; its `invoke` runs every subcommand, so one handler covers them all."""

    def invoke(self, ctx: Any) -> Any:  # a click Context: recent typer vendors its own click
        main = threading.current_thread() is threading.main_thread()
        previous = signal.signal(signal.SIGTERM, _raise_terminated) if main else None
        try:
            return super().invoke(ctx)
        except CoplaneError as exc:
            err_console.print(f"[red]error:[/red] {escape(str(exc))}")  # "[base]" is text, not a style
            raise typer.Exit(exc.exit_code) from exc
        except ValueError as exc:
            message = _settings_error(exc)
            if message is None:
                raise
            err_console.print(f"[red]error:[/red] {escape(message)}")
            raise typer.Exit(CoplaneError.exit_code) from exc
        except OSError as exc:
            if exc.errno not in _PATH_ERRORS or exc.filename is None:
                raise
            # a path the user gave that cannot be read or written (no such folder, no permission,
            # a full disk): the user's environment, not a bug, so the path and the reason suffice
            err_console.print(f"[red]error:[/red] {escape(_path_error(exc))}")
            raise typer.Exit(CoplaneError.exit_code) from exc
        except KeyboardInterrupt as exc:
            err_console.print("interrupted")
            raise typer.Exit(128 + signal.SIGINT) from exc
        except _Terminated as exc:
            err_console.print("terminated")
            raise typer.Exit(128 + signal.SIGTERM) from exc
        finally:
            if previous is not None:
                signal.signal(signal.SIGTERM, previous)


app = typer.Typer(
    cls=_CoplaneGroup,
    name="coplane",
    help="Plane-constraint-aided cooperative positioning for vehicle fleets.",
    no_args_is_help=True,
    add_completion=False,
)


@app.callback()
def main(
    verbose: Annotated[
        bool, typer.Option("--verbose", "-v", help="Log input problems as they are found.")
    ] = False,
) -> None:
    """coplane: replay fleet recordings, run SPP and the cooperative estimators, serve results."""
    logging.basicConfig(
        level=logging.WARNING if verbose else logging.ERROR, format="%(levelname)s %(name)s: %(message)s"
    )


def version() -> None:
    """Print the coplane version."""
    from coplane import __version__

    typer.echo(__version__)


app.command("simulate")(simulate_command)
app.command()(version)
app.command()(spp)
app.command("eval")(eval_)
app.command()(fleet)
app.command()(agent)
app.command()(loadgen)
app.command()(compose)
app.command()(convert)
app.add_typer(certs_app)
app.add_typer(map_app)
app.add_typer(recording_app)
