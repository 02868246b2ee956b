"""The fleet's radio channel: one namespace per station, bridged, shaped once (tbf)."""

from __future__ import annotations

from collections.abc import Callable, Sequence

from sitl.linkemu.namespaces import (
    BACKGROUND_ADDR,
    GROUND_ADDR,
    MAX_DRONES,
    LinkEmuError,
    _next_tag,
    _run,
    _ShapedLink,
    netem_missing,
)

RADIO_DEV = "radio0"
"""Each station's interface on the medium (drones, ground station, background host)."""
MAVLINK_DEV = "mav0"
"""A drone's interface toward its simulated autopilot in the vehicles namespace."""


class SharedMedium(_ShapedLink):
    """A fleet's radio channel: one namespace per drone, one for the ground station, one for
    an iperf3 background host, all bridged in a medium namespace, the bridge's port toward the
    ground station shaped once with tbf (so all of them share one rate and one queue).

    ``delay_s`` and ``loss`` (a probability per datagram) are applied with netem on every
    station's radio interface when the kernel has netem; otherwise :attr:`netem` is False,
    :attr:`impairment_note` says so, and the link has rate and queue only.
    Addresses: ground ``10.199.0.2``, background ``10.199.0.3``, drone i ``10.199.0.(10+i)``
    (/24); drone i <-> vehicles namespace ``10.198.i.2`` <-> ``10.198.i.1`` (/30, unshaped).
    """

    def __init__(
        self,
        *,
        drones: int,
        rate_bit_per_s: float = 6_000_000.0,
        delay_s: float = 0.0,
        loss: float = 0.0,
        queue_limit_bytes: int = 37_500,
        burst_bytes: int = 3_000,
        vehicles: bool = True,
        background: bool = True,
        netem_check: Callable[[], str | None] = netem_missing,
    ) -> None:
        super().__init__()
        if not 1 <= drones <= MAX_DRONES:
            raise ValueError(f"drones must be in 1..{MAX_DRONES}, got {drones}")
        if delay_s < 0 or not 0.0 <= loss < 1.0:
            raise ValueError(f"need delay_s >= 0 and 0 <= loss < 1, got {delay_s}, {loss}")
        if rate_bit_per_s <= 0:
            raise ValueError(f"rate must be > 0, got {rate_bit_per_s}")
        tag = _next_tag()
        self.drones = drones
        self.ns_medium = f"{tag}m"
        self.ns_ground = f"{tag}g"
        self.ns_background: str | None = f"{tag}b" if background else None
        self.ns_vehicles: str | None = f"{tag}v" if vehicles else None
        self.ns_drones = tuple(f"{tag}d{i}" for i in range(drones))
        self.rate_bit_per_s = float(rate_bit_per_s)
        self.delay_s = float(delay_s)
        self.loss = float(loss)
        self.queue_limit_bytes = int(queue_limit_bytes)
        self.burst_bytes = int(burst_bytes)
        self.bottleneck_dev = "gs"
        """The medium namespace's bridge port toward the ground station (shaped)."""
        self._netem_check = netem_check
        self.netem: bool | None = None
        """True: delay/loss applied; False: asked for but netem is missing; None: not asked."""
        self.impairment_note: str | None = None

    def __enter__(self) -> SharedMedium:
        self.open()
        return self

    # -- addresses -------------------------------------------------------------------------

    @staticmethod
    def drone_addr(index: int) -> str:
        return f"10.199.0.{10 + index}"

    @staticmethod
    def vehicle_addrs(index: int) -> tuple[str, str]:
        """(vehicle side, drone side) of drone ``index``'s autopilot link."""
        return f"10.198.{index}.1", f"10.198.{index}.2"

    ground_addr = GROUND_ADDR
    background_addr = BACKGROUND_ADDR

    # iperf3 background: from the background host to the ground station, over the medium.
    @property
    def bg_client_ns(self) -> str:
        if self.ns_background is None:
            raise LinkEmuError("this medium was built without a background host")
        return self.ns_background

    @property
    def bg_server_ns(self) -> str:
        return self.ns_ground

    bg_server_addr = GROUND_ADDR

    # -- building --------------------------------------------------------------------------

    def _stations(self) -> list[tuple[str, str, str]]:
        """(namespace, bridge port name in the medium, address) of every station."""
        out = [(self.ns_ground, self.bottleneck_dev, GROUND_ADDR)]
        if self.ns_background is not None:
            out.append((self.ns_background, "bg", BACKGROUND_ADDR))
        out += [(ns, f"d{i}", self.drone_addr(i)) for i, ns in enumerate(self.ns_drones)]
        return out

    def _build(self) -> None:
        stations = self._stations()
        self._add_ns(self.ns_medium)
        for ns, _, _ in stations:
            self._add_ns(ns)
        m = self.ns_medium
        _run(["ip", "-n", m, "link", "add", "br0", "type", "bridge"])
        for ns, port, addr in stations:
            _run(["ip", "link", "add", RADIO_DEV, "netns", ns, "type", "veth",
                  "peer", "name", port, "netns", m])
            _run(["ip", "-n", m, "link", "set", port, "master", "br0"])
            _run(["ip", "-n", m, "link", "set", port, "up"])
            _run(["ip", "-n", ns, "addr", "add", f"{addr}/24", "dev", RADIO_DEV])
            _run(["ip", "-n", ns, "link", "set", RADIO_DEV, "up"])
        _run(["ip", "-n", m, "link", "set", "br0", "up"])
        if self.ns_vehicles is not None:
            v = self.ns_vehicles
            self._add_ns(v)
            for i, ns in enumerate(self.ns_drones):
                vehicle, drone = self.vehicle_addrs(i)
                _run(["ip", "link", "add", MAVLINK_DEV, "netns", ns, "type", "veth",
                      "peer", "name", f"v{i}", "netns", v])
                for where, dev, addr in ((ns, MAVLINK_DEV, drone), (v, f"v{i}", vehicle)):
                    _run(["ip", "-n", where, "addr", "add", f"{addr}/30", "dev", dev])
                    _run(["ip", "-n", where, "link", "set", dev, "up"])
        self._tbf("add")
        self._impair(stations)

    def _impair(self, stations: list[tuple[str, str, str]]) -> None:
        if self.delay_s == 0 and self.loss == 0:
            return
        asked = f"delay {1000 * self.delay_s:g} ms, loss {100 * self.loss:g} %"
        reason = self._netem_check()
        if reason is not None:
            self.netem = False
            self.impairment_note = (f"{asked} NOT emulated: {reason}; the medium has rate "
                                    f"and queue only")
            return
        for ns, _, _ in stations:
            _run(["tc", "-n", ns, "qdisc", "add", "dev", RADIO_DEV, "root", "netem",
                  "delay", f"{1e6 * self.delay_s:.0f}us", "loss", f"{100 * self.loss:g}%"])
        self.netem = True
        self.impairment_note = f"{asked} per crossing of the medium (netem on every station)"

    @property
    def bottleneck(self) -> tuple[str, str]:
        """The shared bottleneck: the medium's port toward the ground station."""
        return self.ns_medium, self.bottleneck_dev

    def describe(self) -> str:
        """One line for a run's output: topology, rate, queue, and what delay/loss do."""
        impair = self.impairment_note or "no delay/loss asked"
        return (f"{self.drones} drone namespace(s) {self.ns_drones[0]}..; ground "
                f"{self.ns_ground} ({GROUND_ADDR}); bridge in {self.ns_medium}; "
                f"rate {self.rate_bit_per_s / 1e6:g} Mbit/s, queue {self.queue_limit_bytes} B "
                f"(tbf toward the ground station); {impair}")

    def wrap(self, ns: str, argv: Sequence[str]) -> list[str]:
        """``argv`` run inside ``ns`` (for launchers that start processes themselves)."""
        if ns not in self._created:
            raise LinkEmuError(f"{ns} is not a namespace of this medium")
        return ["ip", "netns", "exec", ns, *argv]
