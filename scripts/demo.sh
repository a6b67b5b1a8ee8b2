#!/usr/bin/env bash
# The main job until `secuav-demo wall-hover` exists: fly the wall-hover scenario
# with secuav-sim and the bundled MAVSDK controller (examples/wall_hover_offboard.py).
# Writes the simulator's log and ground truth into out/wall-hover/.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
out=out/wall-hover
mkdir -p "$out"
port=${SECUAV_API_PORT:-14540}
.venv/bin/secuav-sim scenarios/wall_hover.yaml --mavlink "udpout://127.0.0.1:$port" \
  --truth-csv "$out/truth.csv" > "$out/sim.log" 2>&1 &
sim=$!
trap 'kill -INT $sim 2>/dev/null; wait $sim 2>/dev/null || true' EXIT INT TERM
.venv/bin/python examples/wall_hover_offboard.py --url "udpin://127.0.0.1:$port" --seconds "${SECUAV_DEMO_SECONDS:-30}"
echo "demo: simulator log and truth in $out/"
