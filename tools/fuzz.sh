#!/usr/bin/env bash
# Builds the libFuzzer targets (tests/fuzz) with clang and runs each on its corpus.
#   tools/fuzz.sh [SECONDS | --runs N | --build-only] [build dir, default build/fuzz]
# SECONDS (default 20) per target: a hunt with fresh random inputs (`make fuzz`: 300 s each; a longer one: 3600).
# --runs N: the corpus replayed and N inputs more, mutated from a fixed seed (libFuzzer's choices still differ a little
# from run to run): the smoke `make test` runs through ctest (Fuzz.Parsers, --runs 20000). --build-only: build them (`make test` does, before ctest, so the tests' time is theirs).
# A finding leaves its input in <build dir>/findings/<target>/ and makes the script exit non-zero; add it to
# tests/fuzz/corpus/<target>/ once fixed, so every later run replays it.
set -euo pipefail
BUILD_ONLY=0
if [ "${1:-}" = --build-only ]; then
  BUILD_ONLY=1; shift
elif [ "${1:-}" = --runs ]; then
  [[ "${2:-}" =~ ^[0-9]+$ ]] || { echo "fuzz.sh: --runs needs a count" >&2; exit 2; }
  LIMIT=(-runs="$2" -seed=1); WHAT="$2 inputs from seed 1"; FRESH=1; shift 2
else
  [[ "${1:-20}" =~ ^[0-9]+$ ]] || { echo "fuzz.sh: usage: fuzz.sh [SECONDS | --runs N | --build-only] [build dir]" >&2; exit 2; }
  LIMIT=(-max_total_time="${1:-20}"); WHAT="${1:-20} s"; FRESH=0; shift $(( $# > 0 ? 1 : 0 ))
fi
ROOT="$(cd "$(dirname "$0")/.." && pwd)"
BUILD="${1:-$ROOT/build/fuzz}"
command -v clang++ >/dev/null || { echo "fuzz.sh: clang++ not found (make deps installs clang and libclang-rt-14-dev)" >&2; exit 1; }
echo "fuzz: building the libFuzzer targets with clang in $BUILD (the first time several minutes, then only what changed; log: $BUILD.build.log)"
cmake -S "$ROOT/tests/fuzz" -B "$BUILD" -DCMAKE_CXX_COMPILER=clang++ -DCMAKE_BUILD_TYPE=RelWithDebInfo >"$BUILD.configure.log" 2>&1 ||
  { cat "$BUILD.configure.log" >&2; exit 1; }
cmake --build "$BUILD" -j "$(nproc)" >"$BUILD.build.log" 2>&1 || { tail -50 "$BUILD.build.log" >&2; exit 1; }
[ "$BUILD_ONLY" = 1 ] && { echo "fuzz: built in $BUILD"; exit 0; }
echo "fuzz: built; running each parser for $WHAT"
status=0
for t in robot_yaml cell_yaml measurement_csv mcap state_journal urdf rsi_xml; do
  corpus="$ROOT/tests/fuzz/corpus/$t"
  work="$BUILD/work/$t"; findings="$BUILD/findings/$t"
  [ "$FRESH" = 1 ] && rm -rf "$work"  # a repeatable run starts from the committed corpus alone
  mkdir -p "$work" "$findings"
  # New inputs go to work/ (the committed corpus is read, not written); -max_len bounds a huge file's cost.
  if "$BUILD/fuzz_$t" "$work" "$corpus" "${LIMIT[@]}" -max_len=65536 -timeout=10 \
       -rss_limit_mb=2048 -artifact_prefix="$findings/" -print_final_stats=1 >"$BUILD/$t.log" 2>&1; then
    echo "fuzz $t: $(grep -E '^stat::number_of_executed_units' "$BUILD/$t.log" | awk '{print $2}') runs ($WHAT), corpus $(ls "$corpus" | wc -l) + $(ls "$work" | wc -l) new, no finding"
  else
    echo "fuzz $t: FINDING (input in $findings):" >&2
    grep -E 'ERROR|error does not name|SUMMARY|==[0-9]+==' "$BUILD/$t.log" | head -20 >&2
    status=1
  fi
done
exit $status
