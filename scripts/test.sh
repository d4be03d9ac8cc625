#!/usr/bin/env bash
# Install (via setup.sh), lint and type-check the library, then run the whole test suite.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
.venv/bin/ruff check shared services tests bench
.venv/bin/mypy shared/coplane services
.venv/bin/python -m pytest -q "$@"
