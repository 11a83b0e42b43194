#!/usr/bin/env bash
# Sets up the Python virtual environment of the usd-core front end, only what is missing:
#   scripts/setup-venv.sh VENV BUILD_DIR [--fuzz]
# - creates VENV with Debian's /usr/bin/python3 (python3-venv, python3-dev from
#   install-deps.sh) if it has no interpreter yet;
# - installs from PyPI, into VENV only, the packages it lacks (asks the venv, not the
#   network, so a second run is quick); with --fuzz also atheris (make fuzz-usd only);
# - points the venv at the sources (python/) and at the built granular_core module
#   (BUILD_DIR/python) with a .pth file, and writes the `granular` console script.
set -euo pipefail

VENV=${1:?usage: setup-venv.sh VENV BUILD_DIR [--fuzz]}
BUILD_DIR=${2:?usage: setup-venv.sh VENV BUILD_DIR [--fuzz]}
ROOT=$(cd "$(dirname "$0")/.." && pwd)
# usd-core: USD reading and the schema; numpy: arrays for the bindings; pytest: tests;
# pybind11: the bindings' build; jinja2: usdGenSchema (make schemas, schema up-to-date test);
# dask, distributed: granular farm's scheduling (dask[distributed]); pyoidn: Intel Open
# Image Denoise for granular render --denoise (its wheel ships the library).
PY_PACKAGES=(usd-core numpy pytest pybind11 jinja2 dask distributed pyoidn)
# atheris: libFuzzer for Python, for fuzz/fuzz_usd_stage.py (make fuzz-usd); no test needs it.
if [ "${3:-}" = "--fuzz" ]; then
  PY_PACKAGES+=(atheris)
fi

# A venv made while python3-venv was missing has no pip: start it again.
if [ -x "$VENV/bin/python" ] && ! "$VENV/bin/python" -c 'import pip' >/dev/null 2>&1; then
  echo "setup-venv: $VENV has no pip; recreating it"
  rm -rf "$VENV"
fi
if [ ! -x "$VENV/bin/python" ]; then
  echo "setup-venv: creating $VENV"
  /usr/bin/python3 -m venv "$VENV"
fi
PY="$VENV/bin/python"

missing=$("$PY" -c '
import sys
from importlib import metadata
out = []
for p in sys.argv[1:]:
    try:
        metadata.version(p)
    except metadata.PackageNotFoundError:
        out.append(p)
print(" ".join(out))
' "${PY_PACKAGES[@]}")
if [ -n "$missing" ]; then
  echo "setup-venv: installing $missing into $VENV"
  "$PY" -m pip install -q $missing
fi

# Write a file only when its content changes (keeps the second run quiet and quick).
put() {
  local path=$1 content=$2
  if [ ! -f "$path" ] || [ "$(cat "$path")" != "$content" ]; then
    printf '%s\n' "$content" > "$path"
  fi
}
SITE=$("$PY" -c 'import sysconfig; print(sysconfig.get_paths()["purelib"])')
BUILD_ABS=$(mkdir -p "$BUILD_DIR" && cd "$BUILD_DIR" && pwd)
put "$SITE/hdgranular.pth" "$ROOT/python
$BUILD_ABS/python"
VENV_ABS=$(cd "$VENV" && pwd)
put "$VENV/bin/granular" "#!$VENV_ABS/bin/python
# granular: the usd-core front end of hdGranular (python/granular/cli.py).
# The guard: granular farm's LocalCluster starts its workers by spawning Python processes
# that import this file as __mp_main__, and they must not run the command again.
import sys
from granular.cli import main
if __name__ == \"__main__\":
    sys.exit(main())"
chmod +x "$VENV/bin/granular"
