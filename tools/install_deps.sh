#!/usr/bin/env bash
# Installs the Debian 12 packages cellcal needs to build, test and run, and nothing else.
# Used by `make deps` (and so by `make demo` / `make test`) and by docker/Dockerfile: one list, one place.
# Only packages that are missing are installed, so a prepared machine pays nothing.
set -euo pipefail

PACKAGES=(
  build-essential cmake ccache pkg-config
  libeigen3-dev libceres-dev libyaml-cpp-dev
  libgtest-dev libgmock-dev libbenchmark-dev
  libcli11-dev nlohmann-json3-dev
  libwebsocketpp-dev libasio-dev    # cellcal foxglove (the Foxglove WebSocket protocol, recording/foxglove)
  liburdfdom-dev                    # robot descriptions in URDF (cellcal robot import/export, --robot FILE.urdf)
  liborocos-kdl-dev libkdl-parser-dev  # tests: KDL, the independent reference for the URDF conversion
  libfastrtps-dev fastddsgen
  openssl                           # config/security/make_pki.sh (DDS Security test CA and certificates)
  cyclonedds-dev cyclonedds-tools   # tests/interop (a Cyclone DDS peer from cellcal's IDL)
  fastdds-tools iproute2            # tests/netns: the Discovery Server (fastdds discovery), network namespaces (ip)
  gnuplot-nox
  python3                           # make bench: tools/bench/*.sh read bench-cell's --json
  clang libclang-rt-14-dev          # tools/fuzz.sh (libFuzzer + sanitizers)
)

missing=()
for p in "${PACKAGES[@]}"; do
  if ! dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed"; then
    missing+=("$p")
  fi
done

if [ ${#missing[@]} -eq 0 ]; then
  echo "install_deps: all ${#PACKAGES[@]} packages present"
  exit 0
fi

echo "install_deps: installing ${missing[*]}"
SUDO=""
if [ "$(id -u)" -ne 0 ]; then
  if command -v sudo >/dev/null 2>&1; then SUDO="sudo"; else
    echo "install_deps: missing packages (${missing[*]}) and not root; run as root or install them" >&2
    exit 1
  fi
fi
export DEBIAN_FRONTEND=noninteractive
$SUDO apt-get update -qq
$SUDO apt-get install -y -qq --no-install-recommends "${missing[@]}"
