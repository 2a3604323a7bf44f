#!/bin/bash
# ctest Foxglove.LiveCellInAFoxgloveClient: `cellcal foxglove` beside a running `cellcal cell`, read by a Foxglove
# client written by others (@foxglove/ws-protocol, ws, @foxglove/omgidl-serialization from the npm registry), judged
# against the cell's recording and summary (check_live_view.mjs), with the protocol's edges (protocol_edges.mjs).
# Skips (exit 77) with a message only when node/npm or the registry is unreachable.
#   live_view.sh BIN_DIR WORK_DIR CONFIG_DIR
set -euo pipefail
bin_dir=$1 work=$2 config_dir=$3 script_dir=$(cd "$(dirname "$0")" && pwd)
domain=231  # its own DDS domain (cell tests hash into 1..200)
mkdir -p "$work"
if ! command -v node > /dev/null || ! command -v npm > /dev/null; then
  echo "SKIP: node/npm not installed"; exit 77
fi
if [ ! -d "$work/node_modules/@foxglove/ws-protocol" ] || [ ! -d "$work/node_modules/@mcap/core" ]; then
  if ! (cd "$work" && timeout 180 npm install --no-audit --no-fund --silent @mcap/core@2 @foxglove/omgidl-parser@1 \
        @foxglove/omgidl-serialization@1 @foxglove/ws-protocol@0.8 ws@8 > npm.log 2>&1); then
    echo "SKIP: npm registry unreachable (npm install failed: $(tail -1 "$work/npm.log"))"; exit 77
  fi
fi
cp "$script_dir"/*.mjs "$work/"
run="$work/run"
rm -rf "$run" && mkdir -p "$run"
pids=()
cleanup() { for p in "${pids[@]}"; do kill "$p" 2> /dev/null || true; done; }
trap cleanup EXIT

"$bin_dir/cellcal" foxglove --dds-profile cellcal_loopback --domain-id $domain --port 0 --port-file "$run/port" \
  --summary-json "$run/bridge.json" > "$run/bridge.out" 2> "$run/bridge.err" &
bridge=$!
pids+=($bridge)
for _ in $(seq 100); do [ -s "$run/port" ] && break; sleep 0.1; done
[ -s "$run/port" ] || { cat "$run/bridge.err"; echo "FAIL: the bridge did not start listening"; exit 1; }
url="ws://127.0.0.1:$(cat "$run/port")"
(cd "$work" && node live_view_client.mjs "$url" "$run/client.json" "$run/stop") &
pids+=($!)
client=$!
for _ in $(seq 100); do [ -e "$run/stop.ready" ] && break; sleep 0.1; done
[ -e "$run/stop.ready" ] || { echo "FAIL: the client did not subscribe"; exit 1; }

"$bin_dir/cellcal" cell --duration-s 15 --servo --domain-id $domain --work-dir "$run/cell" --record "$run/cell.mcap" \
  --summary-json "$run/cell.json" > "$run/cell.out" 2>&1 &
cell=$!
pids+=($cell)
(cd "$work" && node protocol_edges.mjs "$url")  # a second client, while the cell runs
wait $cell || { cat "$run/cell.out"; echo "FAIL: the cell failed"; exit 1; }
sleep 1
touch "$run/stop"
wait $client
kill -INT $bridge
wait $bridge || { cat "$run/bridge.err"; echo "FAIL: the bridge exited with $?"; exit 1; }
cat "$run/bridge.err" "$run/bridge.out"
(cd "$work" && node check_live_view.mjs "$run/client.json" "$run/cell.mcap" "$run/cell.json" "$run/bridge.json" \
  "$config_dir/foxglove/cellcal.json" "$run/result.json")
