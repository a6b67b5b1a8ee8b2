#!/usr/bin/env bash
# Build SecUAV's base images from Debian packages, for machines that cannot pull from an image registry
# (an air-gapped lab, a CI box behind a proxy). Needs root, debootstrap and a Docker engine.
#
#   sudo bash docker/base-images.sh            # secuav-base/python:bookworm and secuav-base/mosquitto:bookworm
#
# Both are Debian bookworm root file systems made by debootstrap (minbase) from the Debian mirror apt
# already uses here (or DEBIAN_MIRROR), then `docker import`ed:
#   secuav-base/python:bookworm     python3 (3.11), venv, pip, CA certificates: what docker/Dockerfile builds on
#   secuav-base/mosquitto:bookworm  mosquitto and its clients: the compose stack's broker
# With registry access you can skip this and build on python:3.11-slim and eclipse-mosquitto:2 instead
# (docker/README.md says how).
#
# pip inside `docker build` has to trust whatever the machine's pip trusts (a proxy's CA, say). The
# bundle is found the way pip finds it (PIP_CERT, then `pip config get global.cert`, then
# REQUESTS_CA_BUNDLE / SSL_CERT_FILE) and copied into the python image, which points PIP_CERT at it.
# It is never written into the repository.
set -euo pipefail

suite="${DEBIAN_SUITE:-bookworm}"
work="${SECUAV_ROOTFS_DIR:-/var/tmp/secuav-rootfs}"

say() { echo "base-images: $*" >&2; }
die() { say "$*"; exit 1; }

[[ $(id -u) == 0 ]] || die "needs root (debootstrap and chroot)"
command -v debootstrap >/dev/null || die "debootstrap not found (apt-get install debootstrap)"
docker info >/dev/null 2>&1 || die "no Docker engine answers (start dockerd)"

mirror="${DEBIAN_MIRROR:-}"
if [[ -z "$mirror" ]]; then
    mirror="$(grep -hoE '^(URIs:|deb) +https?://[^ ]+' /etc/apt/sources.list.d/*.sources /etc/apt/sources.list 2>/dev/null \
        | grep -v security | head -n1 | awk '{print $2}')" || true
    mirror="${mirror:-http://deb.debian.org/debian}"
fi

ca_bundle() {
    local cert="${PIP_CERT:-}"
    if [[ -z "$cert" ]] && command -v pip >/dev/null; then
        cert="$(pip config get global.cert 2>/dev/null || true)"
    fi
    cert="${cert:-${REQUESTS_CA_BUNDLE:-${SSL_CERT_FILE:-}}}"
    [[ -n "$cert" && -f "$cert" ]] && echo "$cert"
    return 0
}

rootfs() {  # name packages...
    local name="$1"; shift
    local dir="$work/$name"
    rm -rf "$dir"
    mkdir -p "$work"
    say "debootstrap $suite ($name: $*) from $mirror into $dir"
    debootstrap --variant=minbase --include="$(IFS=,; echo "$*")" "$suite" "$dir" "$mirror" >"$work/$name.log" 2>&1 \
        || die "debootstrap failed for $name; see $work/$name.log"
    chroot "$dir" apt-get clean
    rm -rf "$dir"/var/lib/apt/lists/* "$dir"/var/cache/apt/*.bin "$dir"/usr/share/doc/* "$dir"/usr/share/man/*
}

import() {  # name tag changes...
    local name="$1" tag="$2"; shift 2
    local args=()
    for change in "$@"; do args+=(--change "$change"); done
    tar -C "$work/$name" -c . | docker import "${args[@]}" - "$tag" >/dev/null
    say "built $tag ($(docker image inspect -f '{{.Size}}' "$tag" | awk '{printf "%.0f MB", $1/1e6}'))"
}

rootfs python python3 python3-venv python3-pip ca-certificates
cert="$(ca_bundle)"
pip_env=()
if [[ -n "$cert" ]]; then
    install -D -m 644 "$cert" "$work/python/usr/local/share/secuav/pip-ca.crt"
    pip_env=("ENV PIP_CERT=/usr/local/share/secuav/pip-ca.crt")
    say "pip in builds will trust $cert (as pip here does)"
fi
import python "secuav-base/python:$suite" \
    "ENV LANG=C.UTF-8" "ENV PATH=/usr/local/sbin:/usr/local/bin:/usr/sbin:/usr/bin:/sbin:/bin" \
    "${pip_env[@]}" 'CMD ["python3"]'

rootfs mosquitto mosquitto mosquitto-clients
mkdir -p "$work/mosquitto/mosquitto/config" "$work/mosquitto/mosquitto/secrets"
import mosquitto "secuav-base/mosquitto:$suite" \
    "ENV LANG=C.UTF-8" "EXPOSE 1883" 'CMD ["mosquitto", "-c", "/mosquitto/config/mosquitto.conf"]'

rm -rf "$work"
say "done: docker images 'secuav-base/*'"
