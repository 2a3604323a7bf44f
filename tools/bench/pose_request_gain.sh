#!/bin/bash
# What following the engine's pose requests gains in the cell: config/examples/pose_requests.yaml (the demo's TX60
# cell, 30 initial poses then 15 per campaign, the program following cellcal/pose_request) run as four processes
# beside the same cell whose program measures its own random poses (follow_pose_requests: false), for each of SEEDS
# simulation seeds (the robot's errors and drift, the tracker's noise). The launcher judges every calibration
# against the simulated truth on its hold-out poses (the engine never sees them); per seed, the hold-out error after
# 5, 10, 15, 30 and 45 poses, and a figure of both against the poses used.
#   tools/bench/pose_request_gain.sh [BUILD_DIR] [SEEDS] [DURATION_S]
set -euo pipefail
build=$(cd "${1:-build}" && pwd) seeds=${2:-3} duration=${3:-24}
root=$(cd "$(dirname "$0")/../.." && pwd)
out="$build/bench/pose_request_gain"
rm -rf "$out" && mkdir -p "$out"
for seed in $(seq "$seeds"); do
  for follow in true false; do
    name="seed${seed}_$follow"
    sed -e "s|profiles_file: \.\./dds/|profiles_file: $root/config/dds/|" \
        -e "s|robot_file: \.\./robots/|robot_file: $root/config/robots/|" \
        -e "s|^  state_dir: .*|  state_dir: $out/state_$name|" \
        -e "s|^  seed: .*|  seed: $seed|" \
        -e "s|^  follow_pose_requests: .*|  follow_pose_requests: $follow|" \
        "$root/config/examples/pose_requests.yaml" > "$out/$name.yaml"
    "$build/bin/cellcal" cell --config "$out/$name.yaml" --duration-s "$duration" --domain-id 222 \
      --work-dir "$out/run_$name" --summary-json "$out/$name.json" --quiet > "$out/$name.out" 2>&1 ||
      { cat "$out/$name.out"; exit 1; }
  done
done
python3 - "$out" "$seeds" <<'PY'
import json, sys, math
out, seeds = sys.argv[1], int(sys.argv[2])
marks = [5, 10, 15, 30, 45]
def at(history, n):  # the hold-out error of the first calibration with at least n poses
    for v, poses, t_h, mm in history:
        if poses >= n: return mm
    return float('nan')
print(f"pose request gain: config/examples/pose_requests.yaml, {seeds} seeds; hold-out error (mm) after N poses, "
      "following the engine's proposals / the program's random poses")
print("  seed  " + "".join(f"{'N=' + str(n):>20}" for n in marks) + "   followed")
ratios = {n: [] for n in marks}
for s in range(1, seeds + 1):
    f = json.load(open(f"{out}/seed{s}_true.json"))["robots"][0]
    r = json.load(open(f"{out}/seed{s}_false.json"))["robots"][0]
    cells = []
    for n in marks:
        a, b = at(f["holdout_by_version"], n), at(r["holdout_by_version"], n)
        cells.append(f"{a:.4f} / {b:.4f}")
        if a == a and b == b: ratios[n].append(a / b)
    print(f"  {s:<5} " + "".join(f"{c:>20}" for c in cells) + f"   {f['poses_followed']} poses")
    for name, run in (("follow", f), ("random", r)):
        with open(f"{out}/seed{s}_{name}.dat", "w") as d:
            d.write("# poses_used holdout_mm cell_time_h version\n")
            for v, poses, t_h, mm in run["holdout_by_version"]:
                d.write(f"{int(poses)} {mm:.6f} {t_h:.6f} {int(v)}\n")
print("  ratio following / random, geometric mean over the seeds: " +
      ", ".join(f"N={n}: {math.exp(sum(map(math.log, v)) / len(v)):.2f}" for n, v in ratios.items() if v))
PY
{
  echo "set terminal pngcairo size 900,520 noenhanced; set output 'pose_request_gain.png'"
  echo "set title 'Hold-out error after each update: the program follows cellcal/pose_request, or measures random poses'"
  echo "set xlabel 'poses used'; set ylabel 'hold-out position error (mm)'; set logscale y; set grid; set key top right"
  printf "plot "
  for seed in $(seq "$seeds"); do
    printf "'seed%s_follow.dat' using 1:2 with lines lw 2 lc %s title 'seed %s following', " "$seed" "$seed" "$seed"
    printf "'seed%s_random.dat' using 1:2 with lines dt 2 lc %s title 'seed %s random'" "$seed" "$seed" "$seed"
    [ "$seed" -lt "$seeds" ] && printf ", "
  done
  echo
} > "$out/pose_request_gain.gp"
(cd "$out" && gnuplot pose_request_gain.gp) && echo "pose request gain: figure $out/pose_request_gain.png"
