#!/usr/bin/env bash
# A cell's hosts on one machine: four network namespaces, <prefix>-tracker-pc, <prefix>-robot-pc,
# <prefix>-cell-server and <prefix>-cell-server-2 (a second cell server, for a cell whose robots are shared by two
# engines), each with one veth link to a bridge in <prefix>-switch (10.231.0.0/24: .1 tracker-pc, .2 robot-pc, .3
# cell-server, .4 cell-server-2). Nothing is added to the machine's own network namespace; traffic stays between these.
# Run as root (ip netns needs CAP_SYS_ADMIN). docs/deployment.md#several-hosts-on-one-machine.
#
#   cellnet.sh up PREFIX [--no-multicast] [--userspace] [--seed N] [NETEM...]
#                                     make them; --no-multicast: the hosts' links carry no multicast (no route for
#                                     it, multicast off), as a network that blocks it; NETEM (e.g. delay 2ms 0.5ms
#                                     loss 1%) shapes what every host sends: with tc netem where the kernel has it,
#                                     else (or with --userspace) with cellnet_shaper, which does netem's delay, jitter
#                                     and loss in user space (--seed: its random draws). Exit 3 when neither can.
#   cellnet.sh down PREFIX            remove them (what exists of them; no error when already gone)
#   cellnet.sh stats PREFIX           what cellnet_shaper did per link so far (JSON): frames sent, dropped, held
#   cellnet.sh link PREFIX HOST up|down   cut or heal one host's link at the switch (HOST: tracker-pc, robot-pc,
#                                     cell-server, cell-server-2)
#   cellnet.sh check                  exit 0 when namespaces can be made here, else 77 with the reason
#
# Run a process on a host: ip netns exec PREFIX-HOST COMMAND (cellcal cell --host PROCESS=PREFIX-HOST does it).
#
# With cellnet_shaper a host's link is two TAP devices instead of a veth pair, joined by the shaper in the switch's
# namespace: <prefix>h<i> (the host's eth0) and <prefix>s<i> (the bridge's port). The shaper is CELLNET_SHAPER, else
# build/bin/cellnet_shaper beside this script's repository, else on PATH. Its pid, log and stats are in
# /run/cellnet/<prefix>/.
set -u
hosts=(tracker-pc robot-pc cell-server cell-server-2)

die() { echo "cellnet: $1" >&2; exit "${2:-1}"; }

down() {
  local p=$1 run=/run/cellnet/$1
  if [ -f "$run/shaper.pid" ]; then
    local pid
    pid=$(cat "$run/shaper.pid")
    kill -TERM "$pid" 2>/dev/null
    for _ in $(seq 50); do kill -0 "$pid" 2>/dev/null || break; sleep 0.1; done
    kill -KILL "$pid" 2>/dev/null
  fi
  rm -rf "$run"
  for h in "${hosts[@]}" switch; do ip netns del "$p-$h" 2>/dev/null; done
  return 0
}

check() {
  [ "$(id -u)" = 0 ] || { echo "cellnet: not root: network namespaces need CAP_SYS_ADMIN"; return 77; }
  command -v ip >/dev/null || { echo "cellnet: no ip command (Debian package iproute2)"; return 77; }
  local probe="cellnet-probe-$$"
  ip netns add "$probe" 2>/dev/null || { echo "cellnet: ip netns add is refused on this machine"; return 77; }
  ip -n "$probe" link add br0 type bridge 2>/dev/null || { ip netns del "$probe"; echo "cellnet: no bridge support"; return 77; }
  ip link add "cnp$$a" type veth peer name "cnp$$b" 2>/dev/null || { ip netns del "$probe"; echo "cellnet: no veth support"; return 77; }
  ip link del "cnp$$a" 2>/dev/null
  ip netns del "$probe"
  return 0
}

shaper_program() {
  local here
  here=$(cd "$(dirname "$0")/../.." && pwd)
  if [ -n "${CELLNET_SHAPER:-}" ]; then echo "$CELLNET_SHAPER"
  elif [ -x "$here/build/bin/cellnet_shaper" ]; then echo "$here/build/bin/cellnet_shaper"
  else command -v cellnet_shaper; fi
}

up() {
  local p=$1 multicast=1 userspace=0 seed=""
  shift
  while [ $# -gt 0 ]; do
    case "$1" in
      --no-multicast) multicast=0 ;;
      --userspace) userspace=1 ;;
      --seed) [ $# -ge 2 ] || die "--seed needs a number" 2; seed=$2; shift ;;
      *) break ;;
    esac
    shift
  done
  [ ${#p} -le 8 ] || die "prefix '$p': at most 8 characters (interface names are short)" 2
  down "$p"
  ip netns add "$p-switch" || die "ip netns add refused"
  ip -n "$p-switch" link set lo up
  # Shaping: the kernel's netem where it exists, else cellnet_shaper.
  local shaper=""
  if [ $# -gt 0 ]; then
    if [ $userspace = 0 ] && ip netns exec "$p-switch" tc qdisc add dev lo root netem "$@" 2>/dev/null; then
      ip netns exec "$p-switch" tc qdisc del dev lo root
    else
      shaper=$(shaper_program)
      [ -n "$shaper" ] && [ -x "$shaper" ] || {
        down "$p"
        die "no shaping for '$*': this kernel has no netem (sch_netem) and cellnet_shaper was not found (CELLNET_SHAPER)" 3
      }
      local run=/run/cellnet/$p links=() k=0
      mkdir -p "$run"
      for _ in "${hosts[@]}"; do k=$((k + 1)); links+=(--link "${p}h$k:${p}s$k"); done
      ip netns exec "$p-switch" setsid "$shaper" "${links[@]}" ${seed:+--seed "$seed"} --ready-file "$run/ready" \
        --stats-json "$run/shaper.json" "$@" >"$run/shaper.log" 2>&1 &
      echo $! >"$run/shaper.pid"
      for _ in $(seq 50); do [ -f "$run/ready" ] && break; kill -0 "$(cat "$run/shaper.pid")" 2>/dev/null || break; sleep 0.1; done
      [ -f "$run/ready" ] || {
        local log
        log=$(cat "$run/shaper.log")
        down "$p"
        die "cellnet_shaper did not start: $log" 3
      }
    fi
  fi
  ip -n "$p-switch" link add br0 type bridge || { down "$p"; die "no bridge"; }
  ip -n "$p-switch" link set br0 up
  if [ $multicast = 0 ]; then ip -n "$p-switch" link set br0 type bridge mcast_snooping 0; fi
  local i=0
  for h in "${hosts[@]}"; do
    i=$((i + 1))
    local ns="$p-$h" host_if="${p}h$i" sw_if="${p}s$i"
    ip netns add "$ns" || { down "$p"; die "ip netns add $ns refused"; }
    if [ -n "$shaper" ]; then
      # The shaper made both TAP devices in the switch's namespace; the host's goes to the host.
      ip -n "$p-switch" link set "$host_if" netns "$ns" || { down "$p"; die "moving $host_if refused"; }
      # A host may send faster than the shaper reads for a while (a busy machine): netem's default queue, 1000, and
      # then some, before the device drops.
      ip -n "$ns" link set "$host_if" txqueuelen 10000
    else
      ip link add "$host_if" type veth peer name "$sw_if" || { down "$p"; die "veth refused"; }
      ip link set "$host_if" netns "$ns"
      ip link set "$sw_if" netns "$p-switch"
    fi
    ip -n "$p-switch" link set "$sw_if" master br0
    ip -n "$p-switch" link set "$sw_if" up
    ip -n "$ns" link set lo up
    ip -n "$ns" link set "$host_if" name eth0
    ip -n "$ns" addr add "10.231.0.$i/24" dev eth0
    ip -n "$ns" link set eth0 up
    # DDS discovery by multicast (239.255.0.1) goes out of eth0: a default route through it.
    if [ $multicast = 1 ]; then
      ip -n "$ns" route add default dev eth0
    else
      # The switch floods no multicast to this port (without snooping every multicast frame is flooded, and a port
      # with mcast_flood off gets none): a network that blocks multicast.
      ip -n "$p-switch" link set "$sw_if" type bridge_slave mcast_flood off || { down "$p"; die "bridge mcast_flood refused"; }
    fi
    if [ $# -gt 0 ] && [ -z "$shaper" ]; then
      ip netns exec "$ns" tc qdisc add dev eth0 root netem "$@" 2>/dev/null || { down "$p"; die "tc netem $* refused" 3; }
    fi
  done
  local how=""
  if [ $# -gt 0 ]; then how=" (netem $*)"; [ -n "$shaper" ] && how=" (cellnet_shaper $*)"; fi
  echo "cellnet: $p-tracker-pc 10.231.0.1, $p-robot-pc 10.231.0.2, $p-cell-server 10.231.0.3, $p-cell-server-2 10.231.0.4$([ $multicast = 0 ] && echo ', no multicast')$how"
}

stats() {
  local f=/run/cellnet/$1/shaper.json
  [ -f "$f" ] || die "no shaper stats for '$1' ($f): its links are not shaped by cellnet_shaper" 1
  cat "$f"
}

# The switch's port of that host: the host keeps its interface, address and routes (as a PC whose cable is pulled
# at the switch), and DDS finds its peers again once the port is back.
link() {
  local p=$1 h=$2 state=$3 i=0 k=0
  for x in "${hosts[@]}"; do k=$((k + 1)); [ "$x" = "$h" ] && i=$k; done
  [ $i -gt 0 ] || die "no host '$h' (tracker-pc, robot-pc, cell-server, cell-server-2)" 2
  [ "$state" = up ] || [ "$state" = down ] || die "link state '$state': up or down" 2
  ip -n "$p-switch" link set "${p}s$i" "$state"
}

case "${1:-}" in
  up) [ $# -ge 2 ] || die "usage: cellnet.sh up PREFIX [--no-multicast] [--userspace] [--seed N] [NETEM...]" 2; shift; up "$@" ;;
  down) [ $# -eq 2 ] || die "usage: cellnet.sh down PREFIX" 2; down "$2" ;;
  stats) [ $# -eq 2 ] || die "usage: cellnet.sh stats PREFIX" 2; stats "$2" ;;
  link) [ $# -eq 4 ] || die "usage: cellnet.sh link PREFIX HOST up|down" 2; link "$2" "$3" "$4" ;;
  check) check; exit $? ;;
  *) die "usage: cellnet.sh up PREFIX [--no-multicast] [--userspace] [--seed N] [NETEM...] | down PREFIX | stats PREFIX | link PREFIX HOST up|down | check" 2 ;;
esac
