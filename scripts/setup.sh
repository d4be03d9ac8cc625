#!/usr/bin/env bash
# Create .venv (if missing) and install coplane with its dev extra. Idempotent.
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${PYTHON:-python3}
if [ ! -x .venv/bin/python ]; then
  "$PY" -m venv .venv
fi
# System packages, from Debian (CI runs as root on a fresh machine): docker-compose validates
# docker-compose.yml (`config` needs no Docker engine); chromium renders the dashboard headless
# (tests/api/test_api_dashboard.py); the tests fail with a clear message if these are missing.
# jemalloc is the services' allocator (coplane/allocator.py): without it they run on glibc's
# malloc, at about a quarter more fusion CPU.
missing=()
command -v docker-compose >/dev/null 2>&1 || missing+=(docker-compose)
command -v chromium >/dev/null 2>&1 || missing+=(chromium)
{ ldconfig -p || /sbin/ldconfig -p; } 2>/dev/null | grep -q 'libjemalloc\.so\.2' || missing+=(libjemalloc2)
if [ ${#missing[@]} -gt 0 ]; then
  if [ "$(id -u)" = 0 ]; then
    (apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq "${missing[@]}" >/dev/null) \
      || echo "setup: could not install ${missing[*]}" >&2
  else
    echo "setup: please install ${missing[*]} (Debian packages) for the full test suite" >&2
  fi
fi
.venv/bin/python -m pip install -q --upgrade pip
.venv/bin/python -m pip install -q -e '.[dev]'
