#!/usr/bin/env bash
# The layers of docs/ARCHITECTURE.md, checked on the sources: every `#include "cellcal/<layer>/..."` and every DDS
# header must be allowed for the folder the including file lives in. Prints each violation as
# <file>:<line>: <include> (<folder> may include: ...) and exits 1 if there is one.
#   check_layers.sh [source_root]    (default: the repository this script is in)
set -u
root=${1:-$(cd "$(dirname "$0")/../.." && pwd)}
cd "$root" || exit 2

# folder (prefix of the file's path) | cellcal include prefixes it may use | may it include DDS (fastdds, fastrtps,
# fastcdr, the generated cellcal_msgs*)? First matching folder wins, so the more specific come first.
rules=(
  "core/include/cellcal/core/model core/src/model|core/model|no"
  "core/include/cellcal/core/identification core/src/identification|core/model core/identification|no"
  "core/include/cellcal/core/sim core/src/sim|core/model core/identification core/sim|no"
  "core/include/cellcal/core/files core/src/files|core/model core/identification core/files|no"
  "core/include/cellcal/core/campaign core/src/campaign|core/model core/identification core/files core/campaign|no"
  "core/include/cellcal/core/engine core/src/engine|core/model core/identification core/files core/engine|no"
  "core/include/cellcal/core/servo core/src/servo|core/model core/identification core/files core/engine core/servo|no"
  "core/include/cellcal/core/accuracy core/src/accuracy|core/model core/identification core/files core/accuracy|no"
  "core/|core/|no"
  "lab/|core/ lab/|no"
  "recording/mcap/|mcap/ core/files/crc32.hpp|no"
  "recording/foxglove/|foxglove/|no"
  "components/|core/ lab/ components/ servo_compensation.h|yes"
  "recording/|core/ lab/ components/ mcap/ foxglove/ recording/|yes"
)

files=$(find core lab components recording -type f \( -name '*.hpp' -o -name '*.cpp' -o -name '*.h' \) | sort)
[ -n "$files" ] || { echo "check_layers: no sources under $root"; exit 2; }
# One pass of awk over every file (a process per include line took 40 s on a busy 2-core machine).
# shellcheck disable=SC2086
awk -v rules="$(printf '%s\n' "${rules[@]}")" -v nfiles="$(wc -w <<<"$files")" '
BEGIN {
  n = split(rules, R, "\n")
  for (i = 1; i <= n; ++i) {
    split(R[i], part, "|")
    prefixes[i] = part[1]; allowed[i] = part[2]; dds[i] = part[3]
    shown = allowed[i]; gsub(/ /, ",", shown)
    say[i] = "(" part[1] " may include: cellcal/{" shown "}" (part[3] == "yes" ? ", DDS" : "") ")"
  }
}
FNR == 1 {
  rule = 0
  for (i = 1; i <= n && !rule; ++i) {
    np = split(prefixes[i], P, " ")
    for (k = 1; k <= np; ++k) if (index(FILENAME, P[k]) == 1) { rule = i; break }
  }
}
rule && /^[[:space:]]*#[[:space:]]*include/ {
  inc = $0
  sub(/.*#[[:space:]]*include[[:space:]]*[<"]/, "", inc)
  sub(/[">].*/, "", inc)
  ok = 1
  if (inc ~ /^cellcal\//) {
    ok = 0
    na = split(allowed[rule], A, " ")
    for (k = 1; k <= na; ++k) if (index(inc, "cellcal/" A[k]) == 1) ok = 1
  } else if (inc ~ /^(fastdds|fastrtps|fastcdr)\// || inc ~ /^cellcal_msgs/) {
    ok = dds[rule] == "yes"
  }
  if (!ok) { print FILENAME ":" FNR ": " inc " " say[rule]; ++violations }
}
END {
  if (violations > 0) {
    print "check_layers: " violations " include(s) against the layers (docs/ARCHITECTURE.md)"
    exit 1
  }
  print "check_layers: " nfiles " files follow the layers"
}' $files
