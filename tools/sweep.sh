#!/usr/bin/env bash
# The seeded tests over fresh seeds: each test's failure rate, and every failing seed with the command that repeats it.
#   tools/sweep.sh [-n RUNS] [-R CTEST_REGEX] [-E CTEST_EXCLUDE] [-L LABEL] [-j JOBS] [-o OUT_DIR] [BUILD_DIR]
#   make sweep RUNS=100 FILTER='Campaign\.|RegionCheck\.'
# `make test` gives each test a fixed seed of its own (tests/test_support.hpp, testSeed()), so it repeats. This runs
# the tests matching -R (default: all but the bench label) RUNS times (default 100), each run with a fresh
# CELLCAL_TEST_SEED=<n> for every test; a test that never printed a seed in the first run draws nothing at random and
# is dropped from the later runs, as are the regression cases at their fixed seeds (Seed.*). Prints per test: runs, failures, the rate with its 95 % upper bound, and the seeds.
# Writes OUT_DIR/sweep.json (default BUILD_DIR/sweep). Exits 1 when any test's rate is over 2 % (docs/testing.md).
# Interrupted (Ctrl-C, TERM), it summarizes the runs that finished.
set -euo pipefail
RUNS=100 REGEX="." EXCLUDE="" LABEL="" JOBS="$(nproc)" OUT=""
while getopts "n:R:E:L:j:o:h" opt; do
  case $opt in
    n) RUNS=$OPTARG ;; R) REGEX=$OPTARG ;; E) EXCLUDE=$OPTARG ;; L) LABEL=$OPTARG ;; j) JOBS=$OPTARG ;;
    o) OUT=$OPTARG ;;
    *) sed -n '2,10p' "$0" | sed 's/^# \{0,1\}//'; exit 2 ;;
  esac
done
shift $((OPTIND - 1))
ROOT="$(cd "$(dirname "$0")/.." && pwd)"
BUILD="$(cd "${1:-$ROOT/build}" && pwd)"
OUT="${OUT:-$BUILD/sweep}"
[[ "$RUNS" =~ ^[1-9][0-9]*$ ]] || { echo "sweep.sh: -n needs a positive count, got '$RUNS'" >&2; exit 2; }
[ -f "$BUILD/CTestTestfile.cmake" ] || { echo "sweep.sh: $BUILD is not a configured build (make build first)" >&2; exit 2; }
rm -rf "$OUT" && mkdir -p "$OUT" && OUT="$(cd "$OUT" && pwd)"

summarize() {
python3 - "$OUT" "$BUILD" <<'EOF'
import json, math, os, sys, xml.etree.ElementTree as ET
out, build = sys.argv[1], sys.argv[2]
runs = 0
while os.path.exists(os.path.join(out, f"run_{runs + 1}.seed")):
    runs += 1  # the runs that finished (all of them, or those before an interruption)
stats = {}
for k in range(1, runs + 1):
    seed = open(os.path.join(out, f"run_{k}.seed")).read().strip()
    for c in ET.parse(os.path.join(out, f"run_{k}.xml")).getroot().iter("testcase"):
        text = c.findtext("system-out") or ""
        if "CELLCAL_TEST_SEED=" not in text or c.get("name").startswith("Seed."):
            continue  # draws nothing at random, or a regression case at its fixed seed
        s = stats.setdefault(c.get("name"), {"runs": 0, "failed": 0, "skipped": 0, "seeds": []})
        status = c.get("status", "run")
        if status in ("notrun", "disabled") or c.find("skipped") is not None:
            s["skipped"] += 1
            continue
        s["runs"] += 1
        if c.find("failure") is not None or status == "fail":
            s["failed"] += 1
            s["seeds"].append(seed)

def upper95(f, n):
    # Clopper-Pearson's one-sided 95 % upper bound on the failure rate (bisection on the binomial tail).
    if n == 0:
        return 1.0
    if f >= n:
        return 1.0
    lo, hi = f / n, 1.0
    for _ in range(60):
        p = (lo + hi) / 2
        tail = sum(math.comb(n, i) * p**i * (1 - p)**(n - i) for i in range(f + 1))
        lo, hi = (p, hi) if tail > 0.05 else (lo, p)
    return hi

bad = 0
width = max([len(n) for n in stats] + [4])
print(f"\n{'test':<{width}}  runs  failed   rate  95% upper")
for name in sorted(stats):
    s = stats[name]
    rate = s["failed"] / s["runs"] if s["runs"] else 0.0
    s["rate"], s["rate_upper95"] = rate, upper95(s["failed"], s["runs"])
    flag = "  OVER 2 %" if rate > 0.02 else ""
    bad += rate > 0.02
    print(f"{name:<{width}}  {s['runs']:4d}  {s['failed']:6d}  {100 * rate:4.1f} %  {100 * s['rate_upper95']:5.1f} %{flag}")
for name in sorted(stats):
    for seed in stats[name]["seeds"]:
        print(f"failed: (cd {build} && CELLCAL_TEST_SEED={seed} ctest -R '^{name}$' --output-on-failure)")
json.dump({"runs": runs, "tests": stats}, open(os.path.join(out, "sweep.json"), "w"), indent=1)
print(f"\nsweep: {len(stats)} tests, {runs} runs each; {bad} over 2 %; {out}/sweep.json")
sys.exit(1 if bad else 0)
EOF
}
# Ctrl-C (or a time limit's TERM): the rates over the runs that finished.
trap 'echo "sweep: interrupted; the runs that finished:"; summarize; exit $?' INT TERM

draw_seed() { od -An -N8 -tu8 /dev/urandom | tr -d ' '; }
exclude=(); [ -n "$EXCLUDE" ] && exclude=(-E "$EXCLUDE")
label=(); [ -n "$LABEL" ] && label=(-L "$LABEL")
regex="$REGEX"
for ((k = 1; k <= RUNS; ++k)); do
  seed=$(draw_seed)
  echo "sweep: run $k of $RUNS, CELLCAL_TEST_SEED=$seed"
  # ctest exits non-zero when a test fails: that is what is being counted, not an error of the sweep.
  (cd "$BUILD" && CELLCAL_TEST_SEED=$seed ctest -R "$regex" "${exclude[@]}" "${label[@]}" -LE bench -j "$JOBS" --timeout 1800 \
     --output-junit "$OUT/run_$k.xml" > "$OUT/run_$k.log" 2>&1) || true
  [ -f "$OUT/run_$k.xml" ] || { echo "sweep.sh: ctest wrote no results (see $OUT/run_$k.log)" >&2; exit 1; }
  echo "$seed" > "$OUT/run_$k.seed"
  if [ "$k" -eq 1 ]; then
    # Only the tests that drew a seed from testSeed() go on (names escaped for ctest's regex, anchored).
    regex=$(python3 - "$OUT/run_1.xml" <<'EOF'
import re, sys, xml.etree.ElementTree as ET
names = [c.get("name") for c in ET.parse(sys.argv[1]).getroot().iter("testcase")
         if "CELLCAL_TEST_SEED=" in (c.findtext("system-out") or "") and not c.get("name").startswith("Seed.")]
print("|".join("^" + re.escape(n) + "$" for n in names))
EOF
)
    if [ -z "$regex" ]; then echo "sweep: no test matching '$REGEX' draws a seed"; exit 0; fi
    exclude=()  # the names are exact now
    echo "sweep: $(echo "$regex" | tr '|' '\n' | wc -l) tests draw a seed; the later runs take only those"
  fi
done

summarize
