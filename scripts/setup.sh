#!/usr/bin/env bash
# Create .venv and install SecUAV with its test tools. Idempotent: re-runs
# only when pyproject.toml changed. Usage: bash scripts/setup.sh
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${PYTHON:-python3}
if ! "$PY" -c 'import sys; sys.exit(sys.version_info < (3, 11))' 2>/dev/null; then
  echo "SecUAV needs Python 3.11 or newer (found: $("$PY" --version 2>&1))" >&2
  exit 1
fi
if [ ! -x .venv/bin/python ]; then
  if ! "$PY" -m venv .venv 2>/dev/null; then
    echo "python venv module missing; installing python3-venv with apt" >&2
    ${SUDO:-$( [ "$(id -u)" -eq 0 ] || echo sudo )} apt-get update -qq
    ${SUDO:-$( [ "$(id -u)" -eq 0 ] || echo sudo )} apt-get install -y -qq python3-venv
    "$PY" -m venv .venv
  fi
fi
stamp=.venv/.setup-stamp
# The stamp covers the example plugin too: it is installed as a distribution of its own (not editable),
# as a researcher's package would be, so a change to it needs a reinstall.
want=$( (cat pyproject.toml mitm_proxy/net/_fastpath.c; find examples/plugin -path examples/plugin/build -prune -o -type f \
  \( -name '*.py' -o -name '*.yaml' -o -name '*.toml' -o -name '*.md' \) -print | LC_ALL=C sort | xargs cat) \
  | sha256sum | cut -d' ' -f1)
if [ ! -f "$stamp" ] || [ "$(cat "$stamp")" != "$want" ]; then
  echo "setup: installing SecUAV and its dependencies into .venv (first run takes a minute)" >&2
  # The proxy's compiled fast path (mitm_proxy/net/_fastpath.c) needs a C compiler and this Python's headers.
  # Without them the install still succeeds and the proxy takes its pure-Python path (mitm_proxy/README.md).
  pyver=$(.venv/bin/python -c 'import sys; print(f"{sys.version_info[0]}.{sys.version_info[1]}")')
  inc=$(.venv/bin/python -c 'import sysconfig; print(sysconfig.get_paths()["include"])')
  if ! command -v cc >/dev/null || [ ! -f "$inc/Python.h" ]; then
    if command -v apt-get >/dev/null && { [ "$(id -u)" -eq 0 ] || command -v sudo >/dev/null; }; then
      echo "setup: installing gcc and the Python $pyver headers with apt (the proxy's compiled fast path)" >&2
      { ${SUDO:-$( [ "$(id -u)" -eq 0 ] || echo sudo )} apt-get update -qq &&
        ${SUDO:-$( [ "$(id -u)" -eq 0 ] || echo sudo )} apt-get install -y -qq gcc libc6-dev "python$pyver-dev"; } ||
        echo "setup: apt could not install them: the proxy will take its pure-Python path" >&2
    else
      echo "setup: no C compiler or Python headers: the proxy will take its pure-Python path" >&2
    fi
  fi
  .venv/bin/python -m pip install -q --upgrade pip
  .venv/bin/python -m pip install -q -e ".[test]"
  # The example plugin (examples/plugin/): entry points in its own metadata; tests/test_example_plugin.py runs it, examples/plugin/tests/ tests its parts.
  .venv/bin/python -m pip install -q --no-deps --force-reinstall ./examples/plugin
  if ! .venv/bin/python -c 'from mitm_proxy.net import native_udp; raise SystemExit(not native_udp.available())'; then
    echo "setup: the proxy's compiled fast path did not build: secuav-proxy takes its pure-Python path" >&2
  fi
  echo "$want" > "$stamp"
fi
