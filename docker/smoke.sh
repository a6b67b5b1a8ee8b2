#!/usr/bin/env bash
# Build the image, bring the compose stack up, and check it from the host the way a user would:
#
#   bash docker/smoke.sh          (from the repository root, after bash scripts/setup.sh; needs a Docker engine)
#
# 1. the images: secuav-base/* present (docker/base-images.sh), the project image built from the working tree;
# 2. the broker accounts (docker/users.sh) and `compose up`, until the proxy and the simulator report healthy;
# 3. a pymavlink ground station on 127.0.0.1:14550 receives the simulator's telemetry through the proxy;
# 4. anonymous MQTT is refused; `secuav-attack apply` as the operator is acknowledged and moves the
#    attacked wall range while the others stay;
# 5. `compose down` leaves no container or network of the stack behind.
# Exits non-zero naming the step that failed. Works with `docker compose` (v2) and `docker-compose` (v1).
set -uo pipefail
cd "$(dirname "$0")/.."
project="${SMOKE_PROJECT:-secuav-smoke}"
python="${PYTHON:-.venv/bin/python}"
image="${SECUAV_IMAGE:-secuav:latest}"
failed=()

say() { echo "smoke: $*"; }
fail() { say "FAILED: $*"; failed+=("$*"); }
finish() {
    if ((${#failed[@]})); then
        say "${#failed[@]} check(s) failed: ${failed[*]}"
        exit 1
    fi
    say "all checks passed"
    exit 0
}

if docker compose version >/dev/null 2>&1; then compose=(docker compose); else compose=(docker-compose); fi
say "engine $(docker version -f '{{.Server.Version}}' 2>/dev/null || echo none); compose: ${compose[*]} $("${compose[@]}" version --short 2>/dev/null)"
docker info >/dev/null 2>&1 || { fail "no Docker engine answers"; finish; }
for base in secuav-base/python:bookworm secuav-base/mosquitto:bookworm; do
    docker image inspect "$base" >/dev/null 2>&1 || { fail "base image $base missing: run docker/base-images.sh"; finish; }
done
[[ -x "$python" ]] || { fail "$python not found: run scripts/setup.sh first"; finish; }

say "building $image from the working tree (files git tracks or would track)"
start=$(date +%s)
if ! git ls-files -z --cached --others --exclude-standard | tar --null -T - -c \
        | docker build -q -f docker/Dockerfile -t "$image" - >/tmp/secuav-smoke-build.log 2>&1; then
    tail -n 20 /tmp/secuav-smoke-build.log
    fail "docker build (log: /tmp/secuav-smoke-build.log)"
    finish
fi
say "built $image in $(( $(date +%s) - start )) s: $(docker image inspect -f '{{.Size}}' "$image" | awk '{printf "%.0f MB", $1/1e6}')"

[[ -s docker/secrets/mosquitto.passwd ]] || bash docker/users.sh || { fail "docker/users.sh"; finish; }
up() { "${compose[@]}" -p "$project" -f docker/compose.yaml "$@"; }
down() { up down --remove-orphans -t 10 >/dev/null 2>&1; }
trap down EXIT
if ! up up -d --no-build >/tmp/secuav-smoke-up.log 2>&1; then
    tail -n 20 /tmp/secuav-smoke-up.log
    fail "compose up (log: /tmp/secuav-smoke-up.log)"
    finish
fi

health() { docker inspect -f '{{.State.Health.Status}}' "$(up ps -q "$1")" 2>/dev/null; }
for svc in mosquitto proxy sim; do
    for _ in $(seq 60); do [[ "$(health "$svc")" == healthy ]] && break; sleep 1; done
    if [[ "$(health "$svc")" == healthy ]]; then say "$svc healthy"; else fail "$svc not healthy ($(health "$svc"))"; fi
done

before="$("$python" docker/smoke_client.py 127.0.0.1:14550 5)"
say "ground station, 5 s: $before"
grep -q '"DISTANCE_SENSOR"' <<<"$before" || fail "no DISTANCE_SENSOR reached the ground station through the proxy"

anon="$("$python" -m mitm_proxy.tools.attack_cli status --broker mqtt://127.0.0.1:1883 --timeout 2 2>&1)"
if [[ $? == 0 ]]; then fail "an anonymous MQTT client was let in"; else say "anonymous MQTT refused: ${anon##*: }"; fi
as_operator=(--broker mqtt://127.0.0.1:1883 --username operator --password-file docker/secrets/operator)
if out="$("$python" -m mitm_proxy.tools.attack_cli apply wall-spoof --param start_s=0 --param rate_per_s=2 "${as_operator[@]}" 2>&1)"; then
    say "secuav-attack apply as operator: $out"
else
    fail "secuav-attack apply as operator: $out"
fi
sleep 2
after="$("$python" docker/smoke_client.py 127.0.0.1:14550 3)"
say "ground station under attack, 3 s: $after"
if ! "$python" - "$before" "$after" <<'PY'; then
import json, sys
b, a = (json.loads(x)["range_m"] for x in sys.argv[1:3])
moved = a["0"] - b["0"]
steady = max(abs(a[k] - b[k]) for k in b if k != "0")
print(f"smoke: attacked sensor 0 moved {moved:+.2f} m, the others at most {steady:.2f} m")
sys.exit(0 if moved > 1.0 and steady < 0.2 else 1)
PY
    fail "the attack did not change what the ground station receives as expected"
fi
"$python" -m mitm_proxy.tools.attack_cli clear "${as_operator[@]}" >/dev/null 2>&1 || fail "secuav-attack clear"

up down --remove-orphans -t 10 >/tmp/secuav-smoke-down.log 2>&1 || fail "compose down"
trap - EXIT
left="$(docker ps -aq --filter "label=com.docker.compose.project=$project")$(docker network ls -q --filter "label=com.docker.compose.project=$project")"
if [[ -n "$left" ]]; then fail "compose down left containers or networks: $left"; else say "compose down: nothing left running"; fi
finish
