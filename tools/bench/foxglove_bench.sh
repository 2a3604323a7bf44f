#!/bin/bash
# `make bench`: what `cellcal foxglove` costs at the bench cell's load (bench-cell: 8 robots, joint states and tracker
# readings at 1 kHz each, 100 targets/s per robot), with one Foxglove client (@foxglove/ws-protocol from npm)
# subscribed to every topic and decoding every message. bench-cell runs twice, without the bridge and then with it,
# so the cell's own latencies are seen side by side; prints the bridge's CPU, frames sent and dropped, and the
# latency it adds (DDS receipt in the bridge -> decoded in the client) beside the DDS latency.
#   tools/bench/foxglove_bench.sh [BUILD_DIR] [DURATION_S]
set -euo pipefail
build=$(cd "${1:-build}" && pwd) duration=${2:-20}
root=$(cd "$(dirname "$0")/../.." && pwd)
work="$build/npm-foxglove" out="$build/bench/foxglove"
mkdir -p "$work" "$out"
if [ ! -d "$work/node_modules/@foxglove/ws-protocol" ]; then
  (cd "$work" && npm install --no-audit --no-fund --silent @mcap/core@2 @foxglove/omgidl-parser@1 \
     @foxglove/omgidl-serialization@1 @foxglove/ws-protocol@0.8 ws@8)
fi
cp "$root"/tests/foxglove/live_view_client.mjs "$work/"
"$build/bin/cellcal" bench-cell --duration-s "$duration" --domain-id 220 --json "$out/bench_cell_alone.json" \
  > "$out/bench_cell_alone.out" 2>&1
rm -f "$out"/port "$out"/stop "$out"/stop.ready
"$build/bin/cellcal" foxglove --dds-profile cellcal_loopback --domain-id 220 --port 0 --port-file "$out/port" -q \
  --summary-json "$out/bridge.json" > "$out/bridge.out" 2>&1 &
bridge=$!
trap 'kill $bridge 2> /dev/null || true' EXIT
for _ in $(seq 100); do [ -s "$out/port" ] && break; sleep 0.1; done
(cd "$work" && node live_view_client.mjs "ws://127.0.0.1:$(cat "$out/port")" "$out/client.json" "$out/stop" --count-only) &
client=$!
for _ in $(seq 100); do [ -e "$out/stop.ready" ] && break; sleep 0.1; done
"$build/bin/cellcal" bench-cell --duration-s "$duration" --domain-id 220 --json "$out/bench_cell.json" > "$out/bench_cell.out" 2>&1
touch "$out/stop"
wait $client
kill -INT $bridge && wait $bridge || true
node -e '
const [client, bridge, bench, alone] = process.argv.slice(1).map((f) => JSON.parse(require("fs").readFileSync(f, "utf8")));
const pct = (v, p) => { const s = [...v].sort((a, b) => a - b); return s.length ? s[Math.min(s.length - 1, Math.floor(p * s.length))] : NaN; };
const lat = Object.values(client.received).flat().map((x) => x.latency_ms);
const dds = Object.entries(bridge.topics).map(([t, s]) => `${t} ${s.received}` + (s.received ? ` (DDS p50/p99 ${s.dds_latency_p50_ms.toFixed(3)}/${s.dds_latency_p99_ms.toFixed(3)} ms)` : " (not published by bench-cell)"));
console.log(`foxglove bench: bench-cell ${bench.robots ?? 8} robots; the bridge received ${Object.values(bridge.topics).reduce((a, s) => a + s.received, 0)} samples in ${bridge.wall_s.toFixed(1)} s:`);
for (const d of dds) console.log(`  ${d}`);
console.log(`  frames sent ${bridge.server.frames_sent}, dropped for a slow client ${bridge.server.frames_dropped_slow_client}, ${(bridge.server.bytes_sent / 1e6).toFixed(1)} MB`);
console.log(`  bridge CPU ${bridge.cpu_percent_of_one_core.toFixed(1)} % of one core (${bridge.cpu_s.toFixed(2)} s over ${bridge.wall_s.toFixed(1)} s)`);
console.log(`  latency added by the bridge (receipt -> decoded in the client), ${lat.length} messages: p50 ${pct(lat, 0.5).toFixed(3)} ms, p99 ${pct(lat, 0.99).toFixed(3)} ms`);
const cellLine = (b) => `tracker -> CalibrationState p50/p99 ${(b.tracker_to_state_us.p50 / 1e3).toFixed(2)}/${(b.tracker_to_state_us.p99 / 1e3).toFixed(2)} ms, ` +
  `TargetPose -> CompensatedTarget ${(b.target_to_compensated_us.p50 / 1e3).toFixed(2)}/${(b.target_to_compensated_us.p99 / 1e3).toFixed(2)} ms, ` +
  `engine ${b.cpu_share_of_one_core.engine.toFixed(2)} of a core, ${b.calibration_updates} updates`;
console.log(`  the cell without the bridge: ${cellLine(alone)}`);
console.log(`  the cell with the bridge:    ${cellLine(bench)}`);
' "$out/client.json" "$out/bridge.json" "$out/bench_cell.json" "$out/bench_cell_alone.json" | tee "$out/summary.txt"
