#!/usr/bin/env bash
# Build mavlink-router (the C++ router most deployments use) for benchmarks/proxy_bench.py --mavlink-router.
#
#   bash benchmarks/build_mavlink_router.sh            # clones from GitHub; prints the mavlink-routerd path
#   MAVLINK_ROUTER_SRC=/path/to/mavlink-router.git C_LIBRARY_V2_SRC=/path/to/c_library_v2.git \
#     bash benchmarks/build_mavlink_router.sh          # from local git repositories (an offline mirror)
#
# Needs meson, ninja and a C++ compiler (apt: meson ninja-build g++ pkg-config; installed here when run as
# root). The build lives in build/mavlink-router/ (git-ignored); c_library_v2 goes where its submodule would,
# at the commit the router pins when that commit is available.
set -euo pipefail
cd "$(dirname "$0")/.."
ROUTER_SRC="${MAVLINK_ROUTER_SRC:-https://github.com/mavlink-router/mavlink-router.git}"
MAVLINK_SRC="${C_LIBRARY_V2_SRC:-https://github.com/mavlink/c_library_v2.git}"
OUT=build/mavlink-router
if ! command -v meson >/dev/null || ! command -v ninja >/dev/null || ! command -v g++ >/dev/null; then
  if [ "$(id -u)" -eq 0 ] && command -v apt-get >/dev/null; then
    echo "build_mavlink_router: installing meson, ninja-build, g++ with apt" >&2
    apt-get install -y -qq meson ninja-build g++ pkg-config >/dev/null
  else
    echo "build_mavlink_router: needs meson, ninja and g++ (apt-get install meson ninja-build g++ pkg-config)" >&2
    exit 1
  fi
fi
if [ ! -x "$OUT/build/src/mavlink-routerd" ]; then
  rm -rf "$OUT"
  mkdir -p "$OUT"
  git clone -q "$ROUTER_SRC" "$OUT/src"
  pinned=$(git -C "$OUT/src" ls-tree HEAD modules/mavlink_c_library_v2 | awk '{print $3}')
  git clone -q "$MAVLINK_SRC" "$OUT/src/modules/mavlink_c_library_v2"
  if git -C "$OUT/src/modules/mavlink_c_library_v2" cat-file -e "$pinned^{commit}" 2>/dev/null; then
    git -C "$OUT/src/modules/mavlink_c_library_v2" checkout -q "$pinned"
  else
    echo "build_mavlink_router: c_library_v2 $pinned not found; using its newest commit" >&2
  fi
  meson setup "$OUT/build" "$OUT/src" --buildtype=release -Dsystemdsystemunitdir=/tmp/unused >/dev/null
  ninja -C "$OUT/build" >/dev/null
fi
echo "$PWD/$OUT/build/src/mavlink-routerd"
