#!/usr/bin/env bash
# Builds the libFuzzer targets (tests/fuzz) with clang and runs each for a bounded time on its corpus.
#   tools/fuzz.sh [seconds per target, default 20] [build dir, default build/fuzz]
# `make test` runs a smoke through ctest (Fuzz.Parsers, 5 s each: the corpus replayed, a short hunt); `make fuzz`
# 300 s each; a longer hunt: tools/fuzz.sh 3600.
# A finding leaves its input in <build dir>/findings/<target>/ and makes the script exit non-zero; add it to
# tests/fuzz/corpus/<target>/ once fixed, so every later run replays it.
set -euo pipefail
SECONDS_PER_TARGET="${1:-20}"
ROOT="$(cd "$(dirname "$0")/.." && pwd)"
BUILD="${2:-$ROOT/build/fuzz}"
command -v clang++ >/dev/null || { echo "fuzz.sh: clang++ not found (make deps installs clang and libclang-rt-14-dev)" >&2; exit 1; }
echo "fuzz: building the libFuzzer targets with clang in $BUILD (the first time several minutes, then only what changed; log: $BUILD.build.log)"
cmake -S "$ROOT/tests/fuzz" -B "$BUILD" -DCMAKE_CXX_COMPILER=clang++ -DCMAKE_BUILD_TYPE=RelWithDebInfo >"$BUILD.configure.log" 2>&1 ||
  { cat "$BUILD.configure.log" >&2; exit 1; }
cmake --build "$BUILD" -j "$(nproc)" >"$BUILD.build.log" 2>&1 || { tail -50 "$BUILD.build.log" >&2; exit 1; }
echo "fuzz: built; running each parser for $SECONDS_PER_TARGET s"
status=0
for t in robot_yaml cell_yaml measurement_csv mcap state_journal urdf; do
  corpus="$ROOT/tests/fuzz/corpus/$t"
  work="$BUILD/work/$t"; findings="$BUILD/findings/$t"
  mkdir -p "$work" "$findings"
  # New inputs go to work/ (the committed corpus is read, not written); -max_len bounds a huge file's cost.
  if "$BUILD/fuzz_$t" "$work" "$corpus" -max_total_time="$SECONDS_PER_TARGET" -max_len=65536 -timeout=10 \
       -rss_limit_mb=2048 -artifact_prefix="$findings/" -print_final_stats=1 >"$BUILD/$t.log" 2>&1; then
    echo "fuzz $t: $(grep -E '^stat::number_of_executed_units' "$BUILD/$t.log" | awk '{print $2}') runs in ${SECONDS_PER_TARGET} s, corpus $(ls "$corpus" | wc -l) + $(ls "$work" | wc -l) new, no finding"
  else
    echo "fuzz $t: FINDING (input in $findings):" >&2
    grep -E 'ERROR|error does not name|SUMMARY|==[0-9]+==' "$BUILD/$t.log" | head -20 >&2
    status=1
  fi
done
exit $status
