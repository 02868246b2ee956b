"""Link emulation on a real kernel path: network namespaces, veths, a bridge, ``tc``, ``iperf3``.

Two topologies, both made only of namespaces this module creates (addresses ``10.199.x.y`` and
``10.198.x.y`` live inside them; nothing of the host is touched):

- :class:`NetnsLink`: two namespaces joined by a veth pair (``10.199.0.1`` sender,
  ``10.199.0.2`` receiver), the sender->receiver direction shaped with a token bucket
  (``tc tbf``: rate and a byte-bounded queue). The probe experiments of ch. 6 use it.
- :class:`SharedMedium`: a radio channel for a fleet. Every drone has its own namespace, the
  ground station and an ``iperf3`` background host have theirs, and all of them hang on one
  bridge in a "medium" namespace through one veth each. The bridge's port toward the ground
  station is shaped once (tbf), so every drone and the background contend for one queue and
  one rate like stations on one channel. Optional delay and loss use ``netem`` on every
  station's radio interface (each crossing of the medium pays them once), *only when the
  kernel has* ``sch_netem``: :func:`netem_missing` says why not, and the medium reports that
  delay/loss are not emulated rather than faking them. A "vehicles" namespace holds the
  simulated autopilots, each reached from its drone over its own unshaped veth (the
  flight controller's serial line).

Both start processes inside their namespaces and always clean up: on ``close()``/context
exit, on errors while building, at interpreter exit, on SIGTERM/SIGHUP when nobody else
handles them, and for leftovers of dead processes (:func:`cleanup_stale`). Namespace names
carry the pid (``uavle<pid>x<n>...``), so parallel runs never collide.

The package also holds a tiny measurement probe (:mod:`sitl.linkemu.probe`, run as
``python -m sitl.linkemu probe-sender|probe-receiver``): the receiver reports what arrived
and when, as JSON datagrams a few times a second, and the sender lets a goodput constraint
gate an offered load larger than the link.

Modules: :mod:`~sitl.linkemu.namespaces` (cleanup, requirements, :class:`NetnsLink`, tbf),
:mod:`~sitl.linkemu.medium` (:class:`SharedMedium`), :mod:`~sitl.linkemu.background`
(iperf3), :mod:`~sitl.linkemu.probe` (the probe, and the one place a receiver report becomes
link samples). Everything public is re-exported here.
"""

from __future__ import annotations

from sitl.linkemu.background import Iperf3Background
from sitl.linkemu.medium import MAVLINK_DEV, RADIO_DEV, SharedMedium
from sitl.linkemu.namespaces import (
    BACKGROUND_ADDR,
    GROUND_ADDR,
    L2_OVERHEAD_BYTES,
    MAX_DRONES,
    NS_PREFIX,
    RECEIVER_ADDR,
    REQUIREMENTS_HINT,
    SENDER_ADDR,
    LinkEmuError,
    NetnsLink,
    cleanup_stale,
    missing_requirements,
    netem_missing,
    parse_qdisc_counters,
)

__all__ = [
    "BACKGROUND_ADDR",
    "GROUND_ADDR",
    "L2_OVERHEAD_BYTES",
    "MAVLINK_DEV",
    "MAX_DRONES",
    "NS_PREFIX",
    "RADIO_DEV",
    "RECEIVER_ADDR",
    "REQUIREMENTS_HINT",
    "SENDER_ADDR",
    "Iperf3Background",
    "LinkEmuError",
    "NetnsLink",
    "SharedMedium",
    "cleanup_stale",
    "missing_requirements",
    "netem_missing",
    "parse_qdisc_counters",
]
