#!/usr/bin/env bash
# Set up .venv and run the whole test suite (lint + pytest). Usage: bash scripts/test.sh [pytest args]
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
# mosquitto is the broker a deployment would use; its tests run when it is installed.
if ! command -v mosquitto >/dev/null 2>&1 && [ "$(id -u)" -eq 0 ] && command -v apt-get >/dev/null 2>&1; then
  echo "test: installing mosquitto with apt" >&2
  (apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq mosquitto) >/dev/null 2>&1 \
    || echo "test: could not install mosquitto; its tests will be skipped" >&2
fi
.venv/bin/ruff check .
exec .venv/bin/python -m pytest -q "$@"
