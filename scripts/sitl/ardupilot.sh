#!/usr/bin/env bash
# ArduCopter SITL for the SecUAV bench: build it from a tree the user supplies, cache the binary
# outside the repository, and run N vehicles with the bench's parameter file
# (demos/ardupilot/rangefinders.parm, started by demos/sitl.py as secuav-demo height-hold does).
#
#   scripts/sitl/ardupilot.sh build SOURCE     SOURCE: a local ArduPilot tree (submodules checked out)
#                                               or a git URL (cloned with its submodules into the cache)
#   scripts/sitl/ardupilot.sh run [N]          N vehicles (default 1) of the newest cached build;
#                                               vehicle i serves MAVLink on tcp 5760+10*(i+SITL_INSTANCE)
#   scripts/sitl/ardupilot.sh binary           print the path of the newest cached binary
#
# Environment: SECUAV_ARDUPILOT_CACHE (default ~/.cache/secuav/ardupilot), ARDUPILOT_BIN (run this
# binary instead of the cached one), ARDUPILOT_OPT (build optimisation, default -O0: see docs/ardupilot.md),
# ARDUPILOT_JOBS (default 2), SITL_SPEEDUP (default 1), SITL_HOME (lat,lon,alt,heading),
# SITL_EXTRA_PARM (comma-separated extra parameter files, applied after the bench's), SITL_INSTANCE
# (default 0: the first instance number, so two runs on one machine do not share ports or run folders).
# Nothing of ArduPilot is kept in this repository; see docs/ardupilot.md.
set -euo pipefail

here=$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)
cache=${SECUAV_ARDUPILOT_CACHE:-$HOME/.cache/secuav/ardupilot}
opt=${ARDUPILOT_OPT:--O0}
jobs=${ARDUPILOT_JOBS:-2}

# shellcheck source=scripts/sitl/lib.sh
. "$here/lib.sh"

# Python that runs ArduPilot's code generators (waf, mavgen, dronecan_dsdlc): a venv in the cache.
build_python() {
  local venv=$cache/venv
  if [[ ! -x $venv/bin/python ]] || ! "$venv/bin/python" -c 'import em, pexpect, future' 2>/dev/null; then
    python3 -m venv "$venv"
    # empy 4 changed its API; ArduPilot's generators need 3.3.x.
    "$venv/bin/pip" install -q 'empy==3.3.4' pexpect future setuptools packaging
  fi
  echo "$venv/bin/python"
}

# Compiler wrappers. The bench does not need SITL's -O3: at -O3 a busy 2-core machine takes hours,
# and at -O0 nearly all of a unit's cost is parsing the same headers (AP_HAL, GCS, AP_Vehicle...).
# So C++ units also get a precompiled header of those, given as the FIRST -include (gcc ignores
# a .gch that comes after ap_config.h); it includes ap_config.h itself, whose later -include is
# then a no-op. A unit that will not compile with it is compiled again without it, so the
# header can only save time: measured 2.3 s -> 0.1-0.5 s per unit.
write_wrappers() {
  local tools=$1
  rm -rf "$tools/pch"; mkdir -p "$tools/pch"
  printf '%s\n' '#include "ap_config.h"' '#include <AP_HAL/AP_HAL.h>' '#include <AP_Math/AP_Math.h>' \
    '#include <AP_Param/AP_Param.h>' '#include <GCS_MAVLink/GCS.h>' '#include <AP_Logger/AP_Logger.h>' \
    '#include <AP_Vehicle/AP_Vehicle.h>' > "$tools/pch/secuav_pch.h"
  cat > "$tools/cc" <<WRAP
#!/usr/bin/env bash
args=()
for a in "\$@"; do case \$a in -O[0-9s]|-Ofast) a=$opt;; esac; args+=("\$a"); done
# gcc 12 stops on littlefs's unused variable in bd/lfs_filebd.c under ArduPilot's
# -Werror=unused-variable; a warning is enough, and the user's tree stays as it is.
exec ${CC:-gcc} "\${args[@]}" -Wno-error=unused-variable
WRAP
  cat > "$tools/cxx" <<WRAP
#!/usr/bin/env bash
args=(); src=
for a in "\$@"; do
  case \$a in -O[0-9s]|-Ofast) a=$opt;; *.cpp) src=\$a;; esac
  args+=("\$a")
done
[[ -n \$src && \${SECUAV_NO_PCH:-} != 1 ]] || exec ${CXX:-g++} "\${args[@]}"
# the header is compiled with the unit's flags, less its source, output, dependency file and the
# ap_config.h it includes itself; gcc uses a .gch only under the same macros, so one per flag set
# (ArduPilot's copter build has five: libraries, vehicle, SITL's double-precision libraries...)
hdr=(); skip=0
for a in "\${args[@]}"; do
  if (( skip )); then skip=0; continue; fi
  case \$a in
    -o|-include) skip=1; continue;;
    -o*|-c|-MMD|-MD|"\$src") continue;;
  esac
  hdr+=("\$a")
done
dir=$tools/pch/\$(printf '%s\\n' "\${hdr[@]}" | md5sum | cut -c1-12)
pch=\$dir/secuav_pch.h
if [[ ! -e \$pch.gch && ! -e \$pch.failed ]]; then
  mkdir -p "\$dir"
  (
    flock 9
    [[ -e \$pch.gch || -e \$pch.failed ]] && exit 0
    cp "$tools/pch/secuav_pch.h" "\$pch"
    ${CXX:-g++} "\${hdr[@]}" -x c++-header "\$pch" -o "\$pch.gch.tmp" 2>"\$pch.log" \
      && mv "\$pch.gch.tmp" "\$pch.gch" || touch "\$pch.failed"
  ) 9>"\$dir/lock"
fi
if [[ -e \$pch.gch ]]; then
  with=(); put=0
  for a in "\${args[@]}"; do
    if [[ \$a == -include && \$put == 0 ]]; then with+=(-include "\$pch"); put=1; fi
    with+=("\$a")
  done
  (( put )) || with=(-include "\$pch" "\${args[@]}")
  # gcc re-checks warn_unused_result inside the header's inline bodies that ArduPilot's own build
  # never flags (AP_HAL::Semaphore::take_blocking): not an error of this unit
  ${CXX:-g++} "\${with[@]}" -Wno-unused-result 2>/dev/null && exit 0
fi
exec ${CXX:-g++} "\${args[@]}"
WRAP
  chmod +x "$tools/cc" "$tools/cxx"
}

cmd_build() {
  local source=${1:-}
  [[ -n $source ]] || die "build needs SOURCE: a local ArduPilot tree or a git URL"
  local tree
  tree=$(sitl_tree "$source")
  [[ -x $tree/waf && -f $tree/ArduCopter/Copter.cpp ]] || die "$tree: not an ArduPilot tree (no ./waf or ArduCopter/)"
  [[ -f $tree/modules/mavlink/message_definitions/v1.0/common.xml ]] \
    || die "$tree/modules/mavlink: submodule missing (git submodule update --init --recursive)"
  local commit
  commit=$(git -C "$tree" rev-parse --short=10 HEAD 2>/dev/null || echo unversioned)
  local out=$cache/$commit
  local py; py=$(build_python)
  write_wrappers "$out/tools"
  echo "building ArduCopter SITL from $tree ($commit), $opt, -j$jobs; binary goes to $out/arducopter"
  (
    cd "$tree"
    export PATH=$(dirname "$py"):$PATH
    # configure rewrites ap_config.h and so recompiles everything: only when not done with our wrappers
    if ! grep -qs "CXX = \['$out/tools/cxx'\]" build/c4che/sitl_cache.py; then
      CC=$out/tools/cc CXX=$out/tools/cxx nice -n 15 "$py" ./waf configure --board sitl \
        --no-submodule-update --disable-scripting --disable-tests
    fi
    nice -n 15 "$py" ./waf copter -j"$jobs"
  )
  mkdir -p "$out"
  cp "$tree/build/sitl/bin/arducopter" "$out/arducopter.tmp" && mv "$out/arducopter.tmp" "$out/arducopter"
  git -C "$tree" describe --always --dirty 2>/dev/null > "$out/commit" || echo "$commit" > "$out/commit"
  grep -h 'define THISFIRMWARE' "$tree/ArduCopter/version.h" | head -1 | sed 's/.*"\(.*\)".*/\1/' > "$out/version" || true
  cp "$tree/Tools/autotest/default_params/copter.parm" "$out/copter.parm"
  ln -sfn "$out" "$cache/latest"
  echo "$out/arducopter"
}

binary() {
  local bin=${ARDUPILOT_BIN:-$cache/latest/arducopter}
  [[ -x $bin ]] || die "no ArduCopter SITL binary at $bin: run '$0 build SOURCE' first"
  echo "$bin"
}

# The launch lives in the package (demos/sitl.py, with the parameter file demos/ardupilot/rangefinders.parm),
# so that secuav-demo height-hold runs SITL the same way from an installed package; this runs the
# checkout's copy with the checkout's venv.
cmd_run() {
  local root; root=$(cd "$here/../.." && pwd)
  local py=$root/.venv/bin/python
  [[ -x $py ]] || py=python3
  PYTHONPATH=$root${PYTHONPATH:+:$PYTHONPATH} exec "$py" -m demos.sitl run "$@"
}

sitl_main 16 "$@"
