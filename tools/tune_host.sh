#!/usr/bin/env bash
# Raises the kernel's caps on UDP socket buffers to config/sysctl/60-cellcal.conf when they are lower (never lowers
# them), for this boot. Used by `make deps` (and so `make demo` / `make test`). Without root, or where /proc/sys is
# read-only (a container), it says what to run instead and goes on: the cell still runs, but a stall of the host can
# drop best-effort samples (each cellcal process warns at start; docs/deployment.md).
set -uo pipefail
conf="$(cd "$(dirname "$0")/.." && pwd)/config/sysctl/60-cellcal.conf"
while IFS='=' read -r key value; do
  key="$(echo "$key" | tr -d ' ')"
  value="$(echo "$value" | tr -d ' ')"
  case "$key" in ''|\#*) continue ;; esac
  file="/proc/sys/${key//.//}"
  now="$(cat "$file" 2>/dev/null || echo '?')"
  if [ "$now" != '?' ] && [ "$now" -ge "$value" ]; then
    echo "tune_host: $key = $now (>= $value)"
  elif [ -w "$file" ] && echo "$value" > "$file" 2>/dev/null; then
    echo "tune_host: $key raised from $now to $value for this boot (to keep it: cp $conf /etc/sysctl.d/)"
  else
    echo "tune_host: $key = $now, below the $value cellcal's DDS profile asks for, and not writable here;" \
         "as root on the host: sysctl -p $conf" >&2
  fi
done < "$conf"
exit 0
