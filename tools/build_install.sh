#!/usr/bin/env bash
# Builds cellcal (Release, without tests) and installs it into PREFIX (default /usr/local): binaries, the core library
# with its headers and CMake package, the IDL and the shipped configuration. Used by `make install` and by
# docker/Dockerfile, so an image and a machine are built the same way.
# Usage: tools/build_install.sh [PREFIX] [BUILD_DIR]
set -euo pipefail
prefix=${1:-/usr/local}
build=${2:-build-install}
cmake -S . -B "$build" -DCMAKE_BUILD_TYPE=Release -DBUILD_TESTING=OFF
cmake --build "$build" -j "$(nproc)"
cmake --install "$build" --prefix "$prefix"
