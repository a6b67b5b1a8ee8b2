#!/usr/bin/env bash
# The main job: the wall-hover demo (seed Fig. A.5) as a matrix of attack off/on x
# secure stage off/on. Starts the embedded MQTT broker, secuav-sim, secuav-proxy and
# a MAVSDK controller for each case; writes out/wall-hover/report.json and wall_hover.png.
# Extra arguments go to secuav-demo (e.g. --seconds 20, --secure rarse, --attack wall-spoof).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
exec .venv/bin/secuav-demo wall-hover --out out/wall-hover "$@"
