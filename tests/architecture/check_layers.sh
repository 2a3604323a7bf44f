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
  "core/include/cellcal/core/engine core/src/engine|core/model core/identification core/files core/engine|no"
  "core/include/cellcal/core/accuracy core/src/accuracy|core/model core/identification core/files core/accuracy|no"
  "core/|core/|no"
  "lab/|core/ lab/|no"
  "recording/mcap/|mcap/ core/files/crc32.hpp|no"
  "recording/foxglove/|foxglove/|no"
  "components/|core/ lab/ components/|yes"
  "recording/|core/ lab/ components/ mcap/ foxglove/ recording/|yes"
)

violations=0
files=$(find core lab components recording -type f \( -name '*.hpp' -o -name '*.cpp' -o -name '*.h' \) | sort)
[ -n "$files" ] || { echo "check_layers: no sources under $root"; exit 2; }
for f in $files; do
  rule=""
  for r in "${rules[@]}"; do
    for prefix in ${r%%|*}; do
      case "$f" in "$prefix"*) rule=$r; break 2 ;; esac
    done
  done
  [ -n "$rule" ] || continue
  rest=${rule#*|}
  allowed=${rest%%|*}
  dds=${rest##*|}
  while IFS=: read -r line text; do
    inc=$(sed -E 's/.*#include[[:space:]]*[<"]([^">]+)[">].*/\1/' <<<"$text")
    ok=no
    case "$inc" in
      cellcal/*)
        for a in $allowed; do
          case "$inc" in "cellcal/$a"*) ok=yes ;; esac
        done ;;
      fastdds/*|fastrtps/*|fastcdr/*|cellcal_msgs*) [ "$dds" = yes ] && ok=yes ;;
      *) ok=yes ;;
    esac
    if [ "$ok" = no ]; then
      echo "$f:$line: $inc (${rule%%|*} may include: cellcal/{${allowed// /,}}$([ "$dds" = yes ] && echo ', DDS'))"
      violations=$((violations + 1))
    fi
  done < <(grep -n '^[[:space:]]*#[[:space:]]*include' "$f")
done
if [ "$violations" -gt 0 ]; then
  echo "check_layers: $violations include(s) against the layers (docs/ARCHITECTURE.md)"
  exit 1
fi
echo "check_layers: $(wc -w <<<"$files") files follow the layers"
