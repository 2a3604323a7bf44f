#!/bin/bash
# `make bench`: what `diagnose` costs against the geometric calibration it starts from, as ratios measured side by
# side in one run (issue #35: within 10x). At 400 simulated poses (cellcal_bench's BM_Diagnose/400 against
# BM_CalibrateGeometric/400) and on the real UR10 Series A (11,911 rows: `cellcal diagnose` against `cellcal
# calibrate`, each command whole, the fastest of three runs each, interleaved). Exit 1 when a ratio is above 10.
#   tools/bench/diagnose_speed.sh [BUILD_DIR]
set -euo pipefail
build=$(cd "${1:-build}" && pwd)
root=$(cd "$(dirname "$0")/../.." && pwd)
status=0
json=$("$build/bin/cellcal_bench" --benchmark_filter='BM_Diagnose/400|BM_CalibrateGeometric/400' --benchmark_format=json 2>/dev/null)
ms() {  # real_time of benchmark $1 (its unit: ms)
  awk -v want="\"name\": \"$1\"" 'index($0, want) { on = 1 } on && /"real_time"/ { gsub(/[^0-9.e+-]/, "", $2); print $2; exit }' <<<"$json"
}
cal=$(ms BM_CalibrateGeometric/400) diag=$(ms BM_Diagnose/400)
ratio=$(awk -v a="$diag" -v b="$cal" 'BEGIN { printf "%.1f", a / b }')
printf 'diagnose_speed: 400 simulated poses: BM_Diagnose %.1f ms, BM_CalibrateGeometric %.1f ms: %sx (target <= 10x)\n' \
  "$diag" "$cal" "$ratio"
awk -v r="$ratio" 'BEGIN { exit !(r <= 10) }' || status=1
series="$root/../shared/datasets/ipa-robot-accuracy/Series_A/measurements_grid.csv"
if [ ! -f "$series" ]; then
  echo "diagnose_speed: $series missing: Series A not measured"
  exit $status
fi
work="$build/bench/diagnose_speed"
mkdir -p "$work"
"$build/bin/cellcal" import ipa "$series" --out "$work/series_a.csv" > /dev/null
robot="$root/config/robots/ur10.yaml"
best() { sort -n | head -1; }
cal_times=() diag_times=()
for run in 1 2 3; do
  s=$(date +%s.%N); "$build/bin/cellcal" calibrate --robot "$robot" --data "$work/series_a.csv" > /dev/null; e=$(date +%s.%N)
  cal_times+=("$(awk -v s="$s" -v e="$e" 'BEGIN { print e - s }')")
  s=$(date +%s.%N); "$build/bin/cellcal" diagnose --robot "$robot" --data "$work/series_a.csv" --no-progress > /dev/null; e=$(date +%s.%N)
  diag_times+=("$(awk -v s="$s" -v e="$e" 'BEGIN { print e - s }')")
done
cal=$(printf '%s\n' "${cal_times[@]}" | best) diag=$(printf '%s\n' "${diag_times[@]}" | best)
ratio=$(awk -v a="$diag" -v b="$cal" 'BEGIN { printf "%.1f", a / b }')
printf 'diagnose_speed: Series A (11,911 rows): diagnose %.2f s, calibrate %.2f s (fastest of 3 each): %sx (target <= 10x)\n' \
  "$diag" "$cal" "$ratio"
awk -v r="$ratio" 'BEGIN { exit !(r <= 10) }' || status=1
exit $status
