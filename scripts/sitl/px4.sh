#!/usr/bin/env bash
# PX4 SITL with SIH (PX4's own simulator, no Gazebo) for the SecUAV bench: build it from a tree the
# user supplies (or take a tree already built), cache the binary outside the repository, and run N
# quadrotors whose GCS link goes to the proxy.
#
#   scripts/sitl/px4.sh build SOURCE     SOURCE: a local PX4-Autopilot tree (submodules checked out)
#                                         or a git URL (cloned with its submodules into the cache);
#                                         a tree with build/px4_sitl_default/bin/px4 is not rebuilt
#   scripts/sitl/px4.sh run [N]          N SIH quadrotors (default 1) of the newest cached build;
#                                         vehicle k (sysid k+1, PX4 instance k+PX4_INSTANCE) sends its
#                                         GCS link to the proxy at udp 14560+k
#   scripts/sitl/px4.sh binary           print the path of the newest cached binary
#
# Environment: SECUAV_PX4_CACHE (default ~/.cache/secuav/px4), PX4_BIN (run this binary instead of
# the cached one; its etc/ must sit beside its bin/), PX4_JOBS (default 2), PX4_REBUILD=1 (build even
# when the tree has a build), PX4_INSTANCE (default 0: the first PX4 instance number, which moves
# PX4's own ports and run folder so two runs on one machine do not collide), SECUAV_PX4_PROXY_PORT
# (default 14560: vehicle k sends to it + k), SECUAV_PX4_DIRECT_PORT (unset: a second, direct GCS
# link to it + k), PX4_HOME_LAT / PX4_HOME_LON / PX4_HOME_ALT (SIH's home), PX4_NICE (default 5),
# SECUAV_PX4_PARAMS (a file of PX4 `param set` lines, e.g. scripts/sitl/px4/inputs-vision.params,
# sourced before the simulator and EKF2 start).
# Nothing of PX4 is kept in this repository; see docs/px4.md.
set -euo pipefail

here=$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)
cache=${SECUAV_PX4_CACHE:-$HOME/.cache/secuav/px4}
jobs=${PX4_JOBS:-2}
airframe=10040  # sihsim_quadx

# shellcheck source=scripts/sitl/lib.sh
. "$here/lib.sh"

# Python that runs PX4's generators (uORB, parameters, kconfig): a venv in the cache.
build_python() {
  local venv=$cache/venv
  if [[ ! -x $venv/bin/python ]] || ! "$venv/bin/python" -c 'import em, jinja2, kconfiglib, genmsg' 2>/dev/null; then
    python3 -m venv "$venv"
    # empy 4 changed its API; PX4's generators need 3.x.
    "$venv/bin/pip" install -q 'empy<4' jinja2 jsonschema kconfiglib pyros-genmsg packaging future \
      pyyaml toml numpy lark
  fi
  echo "$venv/bin/python"
}

# make px4_sitl_secuav: PX4 merges boards/px4/sitl/secuav.px4board over default.px4board, so the
# modules whose submodules or large files a tree without network lacks (Gazebo, gyro FFT, the DDS
# client) are left out without editing the tree's own board file. The label file is the one file
# this adds to the tree.
build_tree() {
  local tree=$1 py
  py=$(build_python)
  cp "$here/px4/secuav.px4board" "$tree/boards/px4/sitl/secuav.px4board"
  echo "building PX4 SITL (px4_sitl_secuav) in $tree, -j$jobs, under nice -n 15" >&2
  (cd "$tree" && PATH=$(dirname "$py"):$PATH nice -n 15 make px4_sitl_secuav -j"$jobs" >&2)
  echo "$tree/build/px4_sitl_secuav"
}

cmd_build() {
  local source=${1:-}
  [[ -n $source ]] || die "build needs SOURCE: a local PX4-Autopilot tree or a git URL"
  local tree
  tree=$(sitl_tree "$source")
  [[ -f $tree/boards/px4/sitl/default.px4board && -f $tree/src/modules/simulation/simulator_sih/sih.cpp ]] \
    || die "$tree: not a PX4-Autopilot tree with SIH (no boards/px4/sitl/default.px4board or simulator_sih)"
  local built=
  if [[ ${PX4_REBUILD:-} != 1 ]]; then
    for b in "$tree/build/px4_sitl_default" "$tree/build/px4_sitl_secuav"; do
      if [[ -x $b/bin/px4 && -f $b/etc/init.d-posix/airframes/${airframe}_sihsim_quadx ]]; then
        built=$b; echo "taking the build in $b as it is (PX4_REBUILD=1 to build anyway)" >&2; break
      fi
    done
  fi
  if [[ -z $built ]]; then
    [[ -f $tree/src/modules/mavlink/mavlink/message_definitions/v1.0/common.xml ]] \
      || die "$tree/src/modules/mavlink/mavlink: submodule missing (git submodule update --init --recursive)"
    built=$(build_tree "$tree")
  fi
  local commit
  commit=$(git -C "$tree" rev-parse --short=10 HEAD 2>/dev/null || echo unversioned)
  local out=$cache/$commit
  rm -rf "$out.tmp"; mkdir -p "$out.tmp"
  # bin/ (the px4 binary and its px4-* command links) and etc/ (rcS, airframes) are all a run needs
  cp -a "$built/bin" "$built/etc" "$out.tmp/"
  git -C "$tree" describe --always --tags --dirty 2>/dev/null > "$out.tmp/commit" || echo "$commit" > "$out.tmp/commit"
  echo "$built" > "$out.tmp/built-in"
  rm -rf "$out"; mv "$out.tmp" "$out"
  ln -sfn "$out" "$cache/latest"
  echo "$out/bin/px4"
}

binary() {
  local bin=${PX4_BIN:-$cache/latest/bin/px4}
  [[ -x $bin ]] || die "no PX4 SITL binary at $bin: run '$0 build SOURCE' first"
  echo "$bin"
}

cmd_run() {
  local n=${1:-1}
  local first=${PX4_INSTANCE:-0}
  sitl_counts "$n" "$first" PX4_INSTANCE
  local bin; bin=$(binary)
  local etc; etc=$(cd "$(dirname "$bin")/../etc" && pwd) || die "no etc/ beside $(dirname "$bin")"
  local pids=()
  trap 'kill "${pids[@]}" 2>/dev/null; wait' EXIT INT TERM
  for ((k = 0; k < n; k++)); do
    local i=$((first + k))
    local wd=$cache/run/$i
    mkdir -p "$wd"
    # stored parameters and mission wiped: every start is the airframe's defaults and this folder's
    # px4-rc.mavlink (first on PATH, so PX4's rcS sources it instead of its own)
    rm -f "$wd"/parameters*.bson "$wd/dataman"
    PATH=$here/px4:$PATH PX4_SYS_AUTOSTART=$airframe SECUAV_PX4_FIRST_INSTANCE=$first \
      nice -n "${PX4_NICE:-5}" "$bin" -d -i "$i" -w "$wd" "$etc" > "$wd/px4.log" 2>&1 &
    pids+=($!)
    echo "vehicle $k: sysid $((k + 1)), PX4 instance $i, MAVLink to udp 127.0.0.1:$((${SECUAV_PX4_PROXY_PORT:-14560} + k))" \
      "from udp $((18570 + i)), log $wd/px4.log"
  done
  wait -n "${pids[@]}" || true
  echo "a PX4 instance stopped; see $cache/run/*/px4.log" >&2
}

sitl_main 22 "$@"
