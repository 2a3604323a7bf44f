#!/bin/bash
# `make bench`: where one engine saturates on this machine. bench-cell (one engine, one compensation publisher, the
# bench playing every robot's joint states and tracker readings) at 1 kHz per stream for a growing number of robots,
# one run each, side by side: the engine's CPU, its tracker -> CalibrationState latency, the samples it received of
# those published, the stand-stills it turned into updates, and its input queue's peak.
#   tools/bench/engine_saturation.sh [BUILD_DIR] [DURATION_S] [ROBOTS...]
set -euo pipefail
build=$(cd "${1:-build}" && pwd) duration=${2:-10}
shift $(( $# > 2 ? 2 : $# ))
counts=("$@")
[ ${#counts[@]} -gt 0 ] || counts=(8 16 24 32 48)
out="$build/bench/saturation"
mkdir -p "$out"
printf '%-7s %-9s %-22s %-24s %-16s %-14s\n' robots engine "tracker->state p50/p99" "joint states received" "updates/stills" "queue peak"
for n in "${counts[@]}"; do
  "$build/bin/cellcal" bench-cell --robots "$n" --duration-s "$duration" --domain-id 221 --json "$out/r$n.json" \
    > "$out/r$n.log" 2>&1 || { echo "bench-cell --robots $n failed: $(tail -2 "$out/r$n.log")"; continue; }
  python3 - "$out/r$n.json" "$n" <<'PY'
import json, sys
b = json.load(open(sys.argv[1])); n = sys.argv[2]
t = b["tracker_to_state_us"]; js = b["joint_states"]; q = b.get("engine_input_queue", {})
print(f'{n:<7} {b["cpu_share_of_one_core"]["engine"]:<9.2f} {t["p50"]/1e3:>8.2f} / {t["p99"]/1e3:<9.2f}ms '
      f'{js["received_by_engine"]:>10}/{js["published"]:<12} {b["calibration_updates"]:>6}/{b["standstills"]:<8} '
      f'{q.get("peak", "?")}')
PY
done
