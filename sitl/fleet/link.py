"""The link of a run without root: the shaped UDP relay (``sitl.relay_udp``) and its
background traffic, plus the default link figures of ``--netns``."""

from __future__ import annotations

import argparse
import contextlib
import json
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from sitl.fleet_config import FleetPlan

WIFI_G_RATE_BIT_S = 6_000_000.0
"""``--netns`` default link rate: what 802.11g delivers to UDP in practice with several
stations contending (well below its 54 Mbit/s PHY rate)."""
WIFI_G_DELAY_MS = 2.0
"""``--netns`` default one-way delay per crossing of the medium (802.11g channel access and
air time of a frame, a few ms); applied only where the kernel has netem."""
WIFI_G_LOSS_PERCENT = 0.1
"""``--netns`` default residual loss per datagram after 802.11 MAC retransmissions."""


RELAY_RATE_BIT_S = 400_000.0
"""Default rate of the shaped relay (no root): a narrow radio, so four camera streams must
share it and the adaptive constraint has something to adapt to (at 800 kbit/s the drones' ξ
hardly binds and drone3's share over the red was only 1.3x the others', at 400 kbit/s 1.8x)."""
RELAY_QUEUE_BYTES = 20_000
"""The relay's queue: 0.4 s at the default rate, like a radio modem's buffer."""
RELAY_BACKGROUND_SHARE = 0.4
"""Default background step on the relay: this share of its rate from mid-mission."""

RELAY_PRICE_RATE_S = 3.0
"""The relay fleet's ``[middleware] price_rate_s``: the price per byte counts the other
drones' frames only as many as they were heard to send over the last 3 s (without it the
demo fleet sent no image for 8-18 s at a time with the link empty; docs/adaptive.md), all
of a drone's whose worth rose (the red one), and forecasts draw on each stream's last 3 s."""


@dataclass(frozen=True, slots=True)
class Background:
    """iperf3 background traffic: ``rate_bit_s`` from ``start_s`` after the mission start."""

    rate_bit_s: float
    start_s: float = 0.0
    duration_s: float | None = None


def parse_background(text: str) -> Background:
    """``2e6``, ``2e6@20`` (from 20 s) or ``2e6@20+15`` (from 20 s for 15 s)."""
    rate, _, when = text.partition("@")
    start, _, length = when.partition("+")
    try:
        bg = Background(float(rate), float(start) if start else 0.0,
                        float(length) if length else None)
    except ValueError:
        raise ValueError(f"expected BITS[@START_S[+DURATION_S]], got {text!r}") from None
    if bg.rate_bit_s <= 0 or bg.start_s < 0 or (bg.duration_s is not None
                                                  and bg.duration_s <= 0):
        raise ValueError(f"rates and durations must be > 0, got {text!r}")
    return bg


def relay_constraint_params(name: str, rate_bytes_per_s: float) -> dict[str, Any]:
    """The adaptive (or AIMD) constraint scaled to the relay's rate: the parameters tuned on
    the 1 Mbit/s kernel link (``sitl.study.adaptive.REAL_LINK_CONSTRAINTS``) in units of the
    link, with its window T = 0.5 s (the thesis' robots'). ξ is the fleet's budget, so it is
    fitted to the fleet's goodput (every report entry), a frame's transmission time at the
    relay's rate is not queueing, and a lost frame is congestion (``fleet_goodput``,
    ``link_rate_bytes_per_s``, ``loss_is_congestion``: without them ξ sat at 15-20 % of
    this link; with the first two only, relay drops rose). At T = 1 s the budget ξ·T then
    held a full frame (21-32 kB), several drones sent one at once and the 20 kB queue
    dropped them; ξ·T at T = 0.5 s holds one or two half frames (docs/adaptive.md)."""
    params: dict[str, Any] = {"window_s": 0.5, "alpha_bytes_per_s": 0.5 * rate_bytes_per_s,
                              "min_base_latency_s": 0.01,
                              "min_bytes_per_s": 0.05 * rate_bytes_per_s,
                              "fleet_goodput": True, "link_rate_bytes_per_s": rate_bytes_per_s,
                              "loss_is_congestion": True}
    if name.startswith("adaptive"):
        params |= {"learning_rate": 0.1, "min_coef": 0.3, "backlog_clip": 2.0,
                   "scale_bytes_per_s": rate_bytes_per_s,
                   "initial_intercept_bytes_per_s": 0.5 * rate_bytes_per_s}
    elif name == "aimd":  # its default start (62.5 kB/s) is above a slow relay
        params |= {"initial_bytes_per_s": 0.5 * rate_bytes_per_s}
    return params


def relay_description(args: argparse.Namespace) -> str:
    bg = args.background
    load = ("no background load" if bg is None else
            f"background {bg.rate_bit_s / 1e3:g} kbit/s from {bg.start_s:g} s"
            + ("" if bg.duration_s is None else f" for {bg.duration_s:g} s"))
    return (f"shaped UDP relay (user space, sitl.relay): {args.relay_rate / 1e3:g} kbit/s "
            f"token bucket, {args.relay_queue} B queue, {load}")


def relay_argv(args: argparse.Namespace, plan: FleetPlan, stats: Path) -> list[str]:
    assert plan.relay_port is not None
    argv = [sys.executable, "-m", "sitl.relay_udp",
            "--listen", f"127.0.0.1:{plan.relay_port}", "--to", f"127.0.0.1:{plan.gs_udp_port}",
            "--rate", repr(args.relay_rate / 8.0), "--queue", str(args.relay_queue),
            "--stats", str(stats)]
    bg = args.background
    if bg is not None:
        argv += ["--background", f"{bg.rate_bit_s / 8.0!r}@{bg.start_s!r}"
                 + ("" if bg.duration_s is None else f"+{bg.duration_s!r}")]
    return argv


def relay_link(args: argparse.Namespace, stats_path: Path) -> dict[str, Any]:
    """The relay's part of the summary: what ran and its counters."""
    stats: dict[str, Any] = {}
    with contextlib.suppress(OSError, ValueError):
        stats = json.loads(stats_path.read_text(encoding="utf-8"))
    return {"description": relay_description(args), "kind": "relay",
            "rate_bit_s": args.relay_rate, "queue_limit_bytes": args.relay_queue,
            "bottleneck": {"sent_bytes": stats.get("sent_bytes"),
                           "sent_packets": stats.get("sent_packets"),
                           "dropped": stats.get("dropped_packets"),
                           "max_backlog_bytes": stats.get("max_backlog_bytes"),
                           "background_sent_packets": stats.get("background_sent_packets"),
                           "background_dropped_packets":
                               stats.get("background_dropped_packets")} if stats else None}
