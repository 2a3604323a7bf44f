#!/usr/bin/env bash
# check_layers.sh must catch an include that crosses a layer: on a copy of the sources with one planted violation per
# kind (a lower core folder using a higher one, DDS in core, lab using components, components using recording, the
# MCAP library using DDS), it must exit 1 and name each file; on the untouched copy it must exit 0.
set -u
here=$(cd "$(dirname "$0")" && pwd)
root=$(cd "$here/../.." && pwd)
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
for d in core lab components recording; do cp -r "$root/$d" "$tmp/$d"; done
bash "$here/check_layers.sh" "$tmp" >/dev/null || { echo "FAIL: the untouched copy does not pass"; exit 1; }

plant() { mkdir -p "$(dirname "$tmp/$1")"; printf '#include <vector>\n#include %s\n' "$2" >"$tmp/$1"; }
plant core/src/model/planted_a.cpp '"cellcal/core/engine/calibration_engine.hpp"'
plant core/src/engine/planted_b.cpp '<fastdds/dds/domain/DomainParticipant.hpp>'
plant core/src/identification/planted_c.cpp '"cellcal/core/files/robot_yaml.hpp"'
plant lab/src/planted_d.cpp '"cellcal/components/dds_node.hpp"'
plant components/common/src/planted_e.cpp '"cellcal/recording/recording.hpp"'
plant recording/mcap/src/planted_f.cpp '"cellcal_msgs.h"'
plant recording/foxglove/src/planted_g.cpp '"cellcal/components/dds_node.hpp"'
out=$(bash "$here/check_layers.sh" "$tmp")
rc=$?
[ $rc -eq 1 ] || { echo "FAIL: exit $rc with planted violations (want 1)"; echo "$out"; exit 1; }
for f in planted_a planted_b planted_c planted_d planted_e planted_f planted_g; do
  grep -q "$f.cpp:2:" <<<"$out" || { echo "FAIL: $f not reported"; echo "$out"; exit 1; }
done
n=$(grep -c ':2: ' <<<"$out")
[ "$n" -eq 7 ] || { echo "FAIL: $n violations reported, 7 planted"; echo "$out"; exit 1; }
echo "check_layers catches all 7 planted violations and passes the real tree"
