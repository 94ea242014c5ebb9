#!/bin/sh
# vl_in_netns.sh CMD ARGS...: runs CMD in a private network namespace with a multicast loopback for
# LCM (no other traffic on the group) where unshare --net is allowed, else on the host's network.
if [ -z "${VL_IN_NETNS:-}" ] && unshare --net true 2>/dev/null; then
  exec unshare --net env VL_IN_NETNS=1 sh "$0" "$@"
fi
if [ -n "${VL_IN_NETNS:-}" ]; then
  ip link set lo up multicast on && ip route add 224.0.0.0/4 dev lo || exit 1
fi
exec "$@"
