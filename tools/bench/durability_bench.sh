#!/bin/bash
# `make bench`: what keeping the engine's state costs on the latency path, side by side in one run. The demo cell
# (`cellcal cell`, config/cell.yaml) runs ROUNDS times with each engine.durability, alternating (journal, snapshot,
# journal, ...) so both see the same machine: tracker -> CalibrationState p50/p99 and the updates made. Then
# BM_EnginePose: one pose through the engine with the state kept in memory only, as a JSON snapshot per pose, and as a
# journal record per pose.
#   tools/bench/durability_bench.sh [BUILD_DIR] [DURATION_S] [ROUNDS]
set -euo pipefail
build=$(cd "${1:-build}" && pwd) duration=${2:-40} rounds=${3:-2}
root=$(cd "$(dirname "$0")/../.." && pwd)
out="$build/bench/durability"
rm -rf "$out" && mkdir -p "$out"
# The demo cell file with absolute paths (it is read from $out) and the durability set.
variant() {
  sed -e "s|profiles_file: dds/|profiles_file: $root/config/dds/|" \
      -e "s|robot_file: robots/|robot_file: $root/config/robots/|" \
      -e "s|^  state_dir: .*|  state_dir: $out/state_$1\n  durability: $1|" "$root/config/cell.yaml" > "$out/cell_$1.yaml"
}
variant journal
variant snapshot
for round in $(seq "$rounds"); do
  for mode in journal snapshot; do
    "$build/bin/cellcal" cell --config "$out/cell_$mode.yaml" --duration-s "$duration" --domain-id 221 \
      --dds-profile cellcal_loopback --work-dir "$out/run_${mode}_$round" --summary-json "$out/${mode}_$round.json" \
      --quiet > "$out/${mode}_$round.out" 2>&1 || { cat "$out/${mode}_$round.out"; exit 1; }
  done
done
echo "durability bench: demo cell, ${duration} s per run, ${rounds} runs of each engine.durability, alternating"
printf '  %-9s %-4s %8s %14s %14s %16s %16s %14s %14s %15s\n' durability run updates "state p50_us" "state p99_us" \
  "paired p99_us" "update p99_us" "own p50_us" "own p99_us" "verify_last_mm"
for round in $(seq "$rounds"); do
  for mode in journal snapshot; do
    node -e '
const fs = require("fs");
const s = JSON.parse(fs.readFileSync(process.argv[1], "utf8")), e = JSON.parse(fs.readFileSync(process.argv[2], "utf8"));
const r = s.robots[0], er = (e.extra ?? e).robots[r.robot_id];
const f = (x, w) => String(x).padStart(w);
console.log(`  ${process.argv[3].padEnd(9)} ${process.argv[4].padEnd(4)} ${f(s.calibration_updates, 8)} ` +
  `${f(s.latency_us.tracker_to_state_p50.toFixed(0), 14)} ${f(s.latency_us.tracker_to_state_p99.toFixed(0), 14)} ` +
  `${f((er.pairing_latency_p99_ns / 1e3).toFixed(0), 16)} ${f((er.update_latency_p99_ns / 1e3).toFixed(0), 16)} ` +
  `${f((er.decided_to_published_p50_ns / 1e3).toFixed(0), 14)} ${f((er.decided_to_published_p99_ns / 1e3).toFixed(0), 14)} ` +
  `${f(r.verify_after_last_update_mm.toFixed(4), 15)}`);
const p = er.decided_to_published_parts_p50_ns, us = (x) => (x / 1e3).toFixed(0);
console.log(`            own p50 in parts: queued ${us(p.queued)}, pair and update ${us(p.process)}, ` +
  `save ${us(p.persist)}, convert and publish ${us(p.publish)} us`);
const on = er.paired_on;
console.log(`            reading stamped -> received by the engine p50 ${us(er.reading_received_p50_ns)}, ` +
  `p99 ${us(er.reading_received_p99_ns)} us; paired on the own arrival of the reading ${on.reading}, ` +
  `on a later joint state ${on.joint_state}, on a tick ${on.tick}`);' "$out/${mode}_$round.json" \
      "$out/run_${mode}_$round/calibration_engine.stats.json" "$mode" "$round"
  done
done
echo "  state: tracker reading stamped -> its CalibrationState received (the launcher); paired: reading stamped -> paired"
echo "  in the engine (the tracker's path to the engine, any wait for the joint state after the reading, the queue);"
echo "  update: the engine's update of one pose; own: the engine's own share, from receiving the sample that made a"
echo "  reading pairable (the joint state after it) to its version saved and published"
"$build/bin/cellcal_bench" --benchmark_filter=BM_EnginePose --benchmark_repetitions=5 \
  --benchmark_report_aggregates_only=true 2>&1 | grep -E "Benchmark|median"
echo "  BM_EnginePose/N: 0 in memory, 1 JSON snapshot per pose, 2 with fsync, 3 journal record per pose, 4 with fsync"
