#!/usr/bin/env bash
# Installs what the build and tests need on Debian 12, only what is missing.
# Idempotent and quick when everything is present: it asks dpkg, not the network.
set -euo pipefail

DEB_PACKAGES=(
  build-essential cmake ninja-build pkg-config
  libembree-dev libopenimageio-dev libopencolorio-dev libopenvdb-dev libtbb-dev
  libboost-iostreams-dev libgtest-dev nlohmann-json3-dev
  python3 python3-venv python3-dev
  # numpy for Debian's own Python: usdview (an OpenUSD with imaging runs on it) loads the
  # Granular menu, whose density export hands arrays to the granular_core module.
  python3-numpy
)

missing=()
for p in "${DEB_PACKAGES[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done

if [ ${#missing[@]} -gt 0 ]; then
  echo "install-deps: installing ${missing[*]}"
  SUDO=""
  if [ "$(id -u)" != 0 ]; then
    command -v sudo >/dev/null || { echo "install-deps: need root (or sudo) to install: ${missing[*]}" >&2; exit 1; }
    SUDO=sudo
  fi
  $SUDO env DEBIAN_FRONTEND=noninteractive apt-get update -qq
  $SUDO env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends "${missing[@]}"
fi
