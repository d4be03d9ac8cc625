"""`python -m coplane.cli` runs the `coplane` command (as `python -m coplane.cli` did before the package)."""

from coplane.cli import app

app()
