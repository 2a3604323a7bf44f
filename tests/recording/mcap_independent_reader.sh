#!/bin/bash
# ctest McapIndependentReader: cellcal's MCAP files read by @mcap/core from the npm registry, and its recordings'
# CDR messages decoded by @foxglove/omgidl-serialization with the recorded omgidl schemas.
# Skips (exit 77) with a message only when npm or the registry is unreachable.
set -euo pipefail
bin_dir=$1 work=$2 script_dir=$(cd "$(dirname "$0")" && pwd)
mkdir -p "$work"
if ! command -v node > /dev/null || ! command -v npm > /dev/null; then
  echo "SKIP: node/npm not installed"; exit 77
fi
if [ ! -d "$work/node_modules/@foxglove/omgidl-serialization" ]; then
  if ! (cd "$work" && timeout 180 npm install --no-audit --no-fund --silent @mcap/core@2 @foxglove/omgidl-parser@1 \
        @foxglove/omgidl-serialization@1 > npm.log 2>&1); then
    echo "SKIP: npm registry unreachable (npm install failed: $(tail -1 "$work/npm.log"))"; exit 77
  fi
fi
cp "$script_dir/mcap_independent_reader.mjs" "$script_dir/recording_cdr_reader.mjs" "$work/"
# The seed as tests/test_support.hpp's testSeed(): fixed unless CELLCAL_TEST_SEED gives one (or `random`).
seed=${CELLCAL_TEST_SEED:-1}
[ "$seed" = random ] && seed=$(od -An -N4 -tu4 /dev/urandom | tr -d ' ')
[[ "$seed" =~ ^[0-9]+$ ]] || { echo "CELLCAL_TEST_SEED='$seed' is neither a number nor 'random'" >&2; exit 2; }
seed=$((seed % 4294967296))
echo "[   SEED   ] CELLCAL_TEST_SEED=$seed bash $0 $*"
for k in 0 1 2; do
  "$bin_dir/mcap_sample_writer" "$work/sample_$k.mcap" "$work/sample_$k.json" $((seed + k))
  (cd "$work" && node mcap_independent_reader.mjs "sample_$k.mcap" "sample_$k.json")
  "$bin_dir/recording_sample_writer" "$work/recording_$k.mcap" "$work/recording_$k.json" $((seed + k))
  (cd "$work" && node recording_cdr_reader.mjs "recording_$k.mcap" "recording_$k.json")
done
