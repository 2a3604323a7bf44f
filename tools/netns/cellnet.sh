#!/usr/bin/env bash
# A cell's hosts on one machine: four network namespaces, <prefix>-tracker-pc, <prefix>-robot-pc,
# <prefix>-cell-server and <prefix>-cell-server-2 (a second cell server, for a cell whose robots are shared by two
# engines), each with one veth link to a bridge in <prefix>-switch (10.231.0.0/24: .1 tracker-pc, .2 robot-pc, .3
# cell-server, .4 cell-server-2). Nothing is added to the machine's own network namespace; traffic stays between these.
# Run as root (ip netns needs CAP_SYS_ADMIN). docs/deployment.md#several-hosts-on-one-machine.
#
#   cellnet.sh up PREFIX [--no-multicast] [NETEM...]
#                                     make them; --no-multicast: the hosts' links carry no multicast (no route for
#                                     it, multicast off), as a network that blocks it; NETEM (e.g. delay 3ms 1ms loss
#                                     1%) shapes every host's link with tc netem (exit 3 when the kernel has no netem;
#                                     the namespaces are then removed)
#   cellnet.sh down PREFIX            remove them (what exists of them; no error when already gone)
#   cellnet.sh link PREFIX HOST up|down   cut or heal one host's link at the switch (HOST: tracker-pc, robot-pc,
#                                     cell-server, cell-server-2)
#   cellnet.sh check                  exit 0 when namespaces can be made here, else 77 with the reason
#
# Run a process on a host: ip netns exec PREFIX-HOST COMMAND (cellcal cell --host PROCESS=PREFIX-HOST does it).
set -u
hosts=(tracker-pc robot-pc cell-server cell-server-2)

die() { echo "cellnet: $1" >&2; exit "${2:-1}"; }

down() {
  local p=$1
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

up() {
  local p=$1 multicast=1
  shift
  if [ "${1:-}" = "--no-multicast" ]; then multicast=0; shift; fi
  [ ${#p} -le 8 ] || die "prefix '$p': at most 8 characters (interface names are short)" 2
  down "$p"
  ip netns add "$p-switch" || die "ip netns add refused"
  ip -n "$p-switch" link set lo up
  ip -n "$p-switch" link add br0 type bridge || { down "$p"; die "no bridge"; }
  ip -n "$p-switch" link set br0 up
  if [ $multicast = 0 ]; then ip -n "$p-switch" link set br0 type bridge mcast_snooping 0; fi
  local i=0
  for h in "${hosts[@]}"; do
    i=$((i + 1))
    local ns="$p-$h" host_if="${p}h$i" sw_if="${p}s$i"
    ip netns add "$ns" || { down "$p"; die "ip netns add $ns refused"; }
    ip link add "$host_if" type veth peer name "$sw_if" || { down "$p"; die "veth refused"; }
    ip link set "$host_if" netns "$ns"
    ip link set "$sw_if" netns "$p-switch"
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
    if [ $# -gt 0 ]; then
      ip netns exec "$ns" tc qdisc add dev eth0 root netem "$@" 2>/dev/null || {
        down "$p"
        die "tc netem $* refused: this kernel has no netem (sch_netem)" 3
      }
    fi
  done
  echo "cellnet: $p-tracker-pc 10.231.0.1, $p-robot-pc 10.231.0.2, $p-cell-server 10.231.0.3, $p-cell-server-2 10.231.0.4$([ $multicast = 0 ] && echo ', no multicast')${1:+ (netem $*)}"
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
  up) [ $# -ge 2 ] || die "usage: cellnet.sh up PREFIX [--no-multicast] [NETEM...]" 2; shift; up "$@" ;;
  down) [ $# -eq 2 ] || die "usage: cellnet.sh down PREFIX" 2; down "$2" ;;
  link) [ $# -eq 4 ] || die "usage: cellnet.sh link PREFIX HOST up|down" 2; link "$2" "$3" "$4" ;;
  check) check; exit $? ;;
  *) die "usage: cellnet.sh up PREFIX [--no-multicast] [NETEM...] | down PREFIX | link PREFIX HOST up|down | check" 2 ;;
esac
