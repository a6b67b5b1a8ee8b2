#!/usr/bin/env bash
# Set up .venv and run the whole test suite (lint + pytest). Usage: bash scripts/test.sh [pytest args]
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
# mosquitto is the broker a deployment would use; chromium drives the console's page. Their tests run
# when they are installed (under CI=true a missing one fails them).
missing=""
command -v mosquitto >/dev/null 2>&1 || missing="$missing mosquitto"
command -v chromedriver >/dev/null 2>&1 || missing="$missing chromium chromium-driver"
if [ -n "$missing" ] && [ "$(id -u)" -eq 0 ] && command -v apt-get >/dev/null 2>&1; then
  echo "test: installing$missing with apt" >&2
  # shellcheck disable=SC2086  # one word per package
  (apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq $missing) >/dev/null 2>&1 \
    || echo "test: could not install$missing; their tests will be skipped" >&2
fi
.venv/bin/ruff check .
# Side by side on pytest-xdist workers: most flight tests wait on the wall clock (1x), so more workers than the
# 2 cores still pays (docs: README.md#development has the measured runs). loadgroup keeps tests marked
# @pytest.mark.xdist_group(name) on one worker. SECUAV_TEST_WORKERS=0 runs serially; a later -n in "$@" wins.
exec .venv/bin/python -m pytest -q --durations=25 -n "${SECUAV_TEST_WORKERS:-4}" --dist loadgroup "$@"
