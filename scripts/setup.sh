#!/usr/bin/env bash
# Create .venv (if missing) and install coplane with its dev extra. Idempotent.
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${PYTHON:-python3}
if [ ! -x .venv/bin/python ]; then
  "$PY" -m venv .venv
fi
# System tools the tests use (CI runs as root on a fresh Debian machine): docker-compose validates
# docker-compose.yml (no Docker engine is needed for `config`).
if ! command -v docker-compose >/dev/null 2>&1 && [ "$(id -u)" = 0 ]; then
  (apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq docker-compose >/dev/null) \
    || echo "setup: could not install docker-compose" >&2
fi
.venv/bin/python -m pip install -q --upgrade pip
.venv/bin/python -m pip install -q -e '.[dev]'
# Headless Chromium for the dashboard test (tests/test_api_dashboard.py); Debian package, needs root.
if ! command -v chromium >/dev/null; then (apt-get update -qq && apt-get install -y -qq chromium) || echo "could not install chromium"; fi
