"""``--netns``: every drone in its own network namespace on one shaped shared medium.

Without root: the plan and configs a ``--netns`` run writes (per-drone autopilot addresses),
option checks, and the small parsers. With root (marked ``netns``): the bridge topology of
:class:`sitl.linkemu.SharedMedium` (each drone reaches the station from its own address and
its own vehicle link; two drones really share one tbf rate), honest reporting when netem is
missing, cleanup after SIGTERM and of dead runs, and a 2-drone fleet whose companions run in
two different namespaces while images arrive.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
import tomllib
from pathlib import Path

import pytest

from sitl.fleet import FleetError, FleetNetns, make_plan, parse_args
from sitl.fleet_config import companion_toml
from sitl.linkemu import (
    GROUND_ADDR,
    REQUIREMENTS_HINT,
    LinkEmuError,
    SharedMedium,
    cleanup_stale,
    missing_requirements,
    netem_missing,
    parse_qdisc_counters,
)

needs_netns = pytest.mark.skipif(missing_requirements() is not None, reason=REQUIREMENTS_HINT)
FLEET = [sys.executable, "-m", "sitl.cli", "fleet"]


def _namespaces() -> set[str]:
    out = subprocess.run(["ip", "netns", "list"], capture_output=True, text=True, check=True)
    return {line.split()[0] for line in out.stdout.splitlines() if line.split()}


# -- no root needed ------------------------------------------------------------------------------


def test_netns_plan_gives_each_drone_its_own_autopilot_address(tmp_path: Path) -> None:
    plan = make_plan(parse_args(["--netns", "--drones", "3"]), tmp_path / "run", netns=True)
    assert plan.gs_host == GROUND_ADDR
    assert plan.drone_bind_host == "0.0.0.0"  # the vehicles, in their own namespace
    for i, drone in enumerate(plan.drones):
        assert drone.mavlink_host == f"10.198.{i}.2"
        cfg = tomllib.loads(companion_toml(plan, drone))
        assert cfg["mavlink"]["url"] == f"udpin:10.198.{i}.2:{drone.mavlink_port}"
        assert cfg["ground_station"]["host"] == GROUND_ADDR


def test_loopback_plan_is_unchanged(tmp_path: Path) -> None:
    plan = make_plan(parse_args(["--drones", "2"]), tmp_path / "run")
    for drone in plan.drones:
        assert drone.mavlink_host is None
        cfg = tomllib.loads(companion_toml(plan, drone))
        assert cfg["mavlink"]["url"] == f"udpin:127.0.0.1:{drone.mavlink_port}"


def test_link_options_are_checked(capsys: pytest.CaptureFixture[str]) -> None:
    args = parse_args(["--netns", "--link-delay", "5", "--link-loss", "1.5"])
    assert (args.link_delay, args.link_loss) == (5.0, 1.5)
    defaults = parse_args(["--netns"])
    assert (defaults.link_rate, defaults.link_delay, defaults.link_loss) == (6e6, 2.0, 0.1)
    for bad in (["--link-delay", "-1"], ["--link-loss", "100"], ["--link-loss", "-0.1"],
                ["--link-rate", "0"]):
        with pytest.raises(SystemExit):
            parse_args(["--netns", *bad])
    assert "--link" in capsys.readouterr().err


def test_medium_arguments_are_checked() -> None:
    with pytest.raises(ValueError, match="drones"):
        SharedMedium(drones=0)
    with pytest.raises(ValueError, match="drones"):
        SharedMedium(drones=65)
    with pytest.raises(ValueError, match="loss"):
        SharedMedium(drones=1, loss=1.0)
    with pytest.raises(ValueError, match="rate"):
        SharedMedium(drones=1, rate_bit_per_s=0)
    a, b = SharedMedium(drones=2), SharedMedium(drones=2)
    assert set(a.ns_drones).isdisjoint(b.ns_drones)  # names carry pid and a counter
    assert a.ns_drones[0].startswith(f"uavle{os.getpid()}x")
    assert [a.drone_addr(i) for i in range(2)] == ["10.199.0.10", "10.199.0.11"]


def test_qdisc_counters_are_read_from_tc_output() -> None:
    text = ("qdisc tbf 1: root refcnt 2 rate 2Mbit burst 3000b lat 130ms \n"
            " Sent 841364 bytes 767 pkt (dropped 11, overlimits 402 requeues 0) \n"
            " backlog 0b 0p requeues 0\n")
    assert parse_qdisc_counters(text) == {"sent_bytes": 841364, "sent_packets": 767,
                                          "dropped": 11, "overlimits": 402}
    assert parse_qdisc_counters("qdisc noqueue 0: root") is None


# -- root: the medium itself -----------------------------------------------------------------------

RECEIVER = """
import json, socket, sys, time
s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
s.bind(("0.0.0.0", int(sys.argv[1])))
s.settimeout(0.2)
print("ready", flush=True)
got = {}
arrivals = []
t_end = time.time() + float(sys.argv[2])
while time.time() < t_end:
    try:
        data, (host, _) = s.recvfrom(65535)
    except TimeoutError:
        continue
    arrivals.append(time.time())
    got[host] = got.get(host, 0) + len(data)
print(json.dumps({"bytes": got, "first": arrivals[0], "last": arrivals[-1],
                  "n": len(arrivals)}), flush=True)
"""

SENDER = """
import socket, sys, time
s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
host, port, rate, seconds = sys.argv[1], int(sys.argv[2]), float(sys.argv[3]), float(sys.argv[4])
t0 = float(sys.argv[5])  # a common start, so both drones contend all the time
payload = bytes(1200)
time.sleep(max(0.0, t0 - time.time()))
sent = 0
while time.time() < t0 + seconds:
    if sent * 8 < rate * (time.time() - t0):
        s.sendto(payload, (host, port))
        sent += len(payload)
    else:
        time.sleep(0.001)
"""


@pytest.mark.netns
@needs_netns
@pytest.mark.timeout(60)
def test_drones_share_one_shaped_medium_from_their_own_namespaces() -> None:
    """Two drones offering 1.6 Mbit/s each into a 1 Mbit/s medium get 1 Mbit/s together
    (one rate, one queue), each from its own address. Were each drone shaped on its own,
    the sum would be about twice that."""
    rate, seconds = 1_000_000.0, 3.0
    with SharedMedium(drones=2, rate_bit_per_s=rate, queue_limit_bytes=15_000) as medium:
        assert set(medium.namespaces) <= _namespaces()
        receiver = medium.popen(medium.ns_ground, [sys.executable, "-c", RECEIVER, "47100",
                                                   str(seconds + 2.5)],
                                stdout=subprocess.PIPE, text=True)
        assert receiver.stdout is not None
        assert receiver.stdout.readline().strip() == "ready"
        t0 = repr(time.time() + 1.0)
        senders = [medium.popen(ns, [sys.executable, "-c", SENDER, GROUND_ADDR, "47100",
                                     "1.6e6", str(seconds), t0])
                   for ns in medium.ns_drones]
        for proc in senders:
            assert proc.wait(timeout=20) == 0
        report = json.loads(receiver.communicate(timeout=20)[0].strip().splitlines()[-1])
        counters = parse_qdisc_counters(medium.qdisc_stats())
    got = report["bytes"]
    assert set(got) == {"10.199.0.10", "10.199.0.11"}
    # The queue stays backlogged from the first arrival to the last (3.2 Mbit/s offered),
    # so arrivals come at the shaped rate; tbf counts Ethernet/IP/UDP headers.
    payload_rate = (sum(got.values()) - 1200) * 8 / (report["last"] - report["first"])
    capacity = medium.payload_capacity_bytes_per_s(1200) * 8
    print(f"received {payload_rate / 1e6:.3f} Mbit/s of payload, capacity "
          f"{capacity / 1e6:.3f}; per drone {got}; bottleneck {counters}")
    assert 0.85 * capacity < payload_rate < 1.05 * capacity  # 1 Mbit/s shared, not 2
    assert min(got.values()) > 0.25 * sum(got.values())  # both contend, neither starves
    assert counters is not None and counters["dropped"] > 0  # 3.2 Mbit/s offered to 1


@pytest.mark.netns
@needs_netns
@pytest.mark.timeout(60)
def test_each_drone_reaches_only_its_own_vehicle_link() -> None:
    with SharedMedium(drones=2, rate_bit_per_s=2e6) as medium:
        assert medium.ns_vehicles is not None
        for i, ns in enumerate(medium.ns_drones):
            routes = subprocess.run(["ip", "-n", ns, "-4", "route"], capture_output=True,
                                    text=True, check=True).stdout
            assert f"10.198.{i}.0/30" in routes
            assert f"10.198.{1 - i}.0/30" not in routes
            assert "10.199.0.0/24" in routes
            assert "default" not in routes  # nothing leads out of our namespaces
        addrs = subprocess.run(["ip", "-n", medium.ns_vehicles, "-4", "addr"],
                               capture_output=True, text=True, check=True).stdout
        assert "10.198.0.1/30" in addrs and "10.198.1.1/30" in addrs
    assert not set(medium.ns_drones) & _namespaces()


@pytest.mark.netns
@needs_netns
@pytest.mark.timeout(60)
def test_missing_netem_is_reported_not_faked() -> None:
    with SharedMedium(drones=1, delay_s=0.02, loss=0.01,
                      netem_check=lambda: "no sch_netem here") as medium:
        assert medium.netem is False
        assert medium.impairment_note is not None
        assert "NOT emulated" in medium.impairment_note
        assert "no sch_netem here" in medium.impairment_note
        assert "NOT emulated" in medium.describe()
        qdiscs = subprocess.run(["tc", "-n", medium.ns_drones[0], "qdisc", "show"],
                                capture_output=True, text=True, check=True).stdout
        assert "netem" not in qdiscs
    with SharedMedium(drones=1) as plain:
        assert plain.netem is None and plain.impairment_note is None


@pytest.mark.netns
@needs_netns
@pytest.mark.skipif(netem_missing() is not None, reason=f"{netem_missing()}")
@pytest.mark.timeout(60)
def test_netem_delay_is_applied_on_every_station_when_available() -> None:
    with SharedMedium(drones=1, delay_s=0.02) as medium:
        assert medium.netem is True
        for ns in (medium.ns_drones[0], medium.ns_ground):
            qdiscs = subprocess.run(["tc", "-n", ns, "qdisc", "show", "dev", "radio0"],
                                    capture_output=True, text=True, check=True).stdout
            assert "netem" in qdiscs and "delay 20ms" in qdiscs


@pytest.mark.netns
@needs_netns
@pytest.mark.timeout(60)
def test_a_failure_half_way_removes_what_was_built(monkeypatch: pytest.MonkeyPatch) -> None:
    def broken_tbf(self: SharedMedium, verb: str) -> None:
        assert len(self.namespaces) == 6  # m, g, b, d0, d1, v: all but the shaping
        raise LinkEmuError("tc: simulated failure")

    monkeypatch.setattr(SharedMedium, "_tbf", broken_tbf)
    link = FleetNetns(drones=2, rate_bit_s=1e6)
    m = link.medium
    with pytest.raises(FleetError, match="cannot build the shared link: tc: simulated failure"):
        link.open()
    assert m.namespaces == []
    assert not {m.ns_medium, m.ns_ground, m.ns_vehicles, m.ns_background, *m.ns_drones} \
        & _namespaces()


HOLDER = """
import sys, time
from sitl.linkemu import SharedMedium
m = SharedMedium(drones=1)
m.open()
print(" ".join(m.namespaces), flush=True)
time.sleep(60)
"""


@pytest.mark.netns
@needs_netns
@pytest.mark.timeout(60)
def test_namespaces_go_on_sigterm_and_after_a_dead_owner() -> None:
    proc = subprocess.Popen([sys.executable, "-c", HOLDER], stdout=subprocess.PIPE, text=True)
    assert proc.stdout is not None
    names = set(proc.stdout.readline().split())
    assert len(names) == 5 and names <= _namespaces()  # medium, ground, bg, vehicles, d0
    proc.send_signal(signal.SIGTERM)
    assert proc.wait(timeout=20) == 128 + signal.SIGTERM
    assert not names & _namespaces()
    # A run killed with SIGKILL leaves its namespaces; the next start removes them.
    dead = subprocess.Popen(["true"])
    dead.wait()
    stale = f"uavle{dead.pid}x1d3"
    subprocess.run(["ip", "netns", "add", stale], check=True)
    try:
        assert stale in cleanup_stale()
    finally:
        subprocess.run(["ip", "netns", "del", stale], capture_output=True, check=False)
    assert stale not in _namespaces()


# -- root: the fleet -----------------------------------------------------------------------------


def _pid_of(marker: str) -> int | None:
    """The pid of a process whose command line mentions ``marker``."""
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            cmdline = (entry / "cmdline").read_bytes().replace(b"\0", b" ").decode()
        except OSError:
            continue
        if marker in cmdline and "netns exec" not in cmdline:
            return int(entry.name)
    return None


def _netns_of(pid: int) -> str:
    out = subprocess.run(["ip", "netns", "identify", str(pid)], capture_output=True,
                         text=True, check=False)
    return out.stdout.strip()


@pytest.mark.netns
@needs_netns
@pytest.mark.timeout(300)
def test_fleet_runs_each_drone_in_its_own_namespace(tmp_path: Path) -> None:
    """The run ends by itself (8 s of mission); the timeouts are only a safety net, sized for
    a loaded 2-core machine under xdist: 64-72 s at load 13, and the launcher now also waits
    for the companions' optimisers to warm up (a minute more on a cold numba cache)."""
    run_dir = tmp_path / "run"
    summary_path = tmp_path / "summary.json"
    proc = subprocess.Popen([*FLEET, "--out", str(run_dir), "--summary-json", str(summary_path),
                             "--netns", "--drones", "2", "--duration", "8", "--rate", "3",
                             "--mcts-iterations", "100", "--quiet"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    where: dict[str, str] = {}
    deadline = time.monotonic() + 200  # (the loop ends when all three are found)
    while len(where) < 3 and proc.poll() is None and time.monotonic() < deadline:
        for name, marker in (("drone1", "drones/drone1/companion.toml"),
                             ("drone2", "drones/drone2/companion.toml"),
                             ("station", "ground_station.toml")):
            pid = _pid_of(f"{run_dir}/{marker}")
            if name not in where and pid is not None and _netns_of(pid):
                where[name] = _netns_of(pid)
        time.sleep(0.3)
    try:
        out, err = proc.communicate(timeout=max(30.0, deadline + 60 - time.monotonic()))
    finally:
        if proc.poll() is None:  # a hung launcher still takes down its namespaces
            proc.terminate()
            proc.communicate(timeout=60)
    print(out[-2500:])
    assert proc.returncode == 0, err[-3000:]
    summary = json.loads(summary_path.read_text())
    link = summary["link"]
    assert where == {"drone1": link["namespaces"]["drones"][0],
                     "drone2": link["namespaces"]["drones"][1],
                     "station": link["namespaces"]["ground_station"]}
    assert len(set(where.values())) == 3
    for drone in summary["drones"].values():
        assert drone["received"] > 0
    assert link["bottleneck"]["sent_bytes"] > 0  # the images crossed the shaped port
    if netem_missing() is not None:
        assert link["netem"] is False
        assert "NOT emulated" in out and "NOT emulated" in err
    else:
        assert link["netem"] is True
    assert not set(where.values()) & _namespaces()


@pytest.mark.slow  # about 50 s: three companions, vehicles and a station in namespaces
@pytest.mark.netns
@needs_netns
@pytest.mark.timeout(150)
def test_fleet_peers_share_the_medium_across_namespaces(tmp_path: Path) -> None:
    """``--peers --netns`` (issue 15): each companion in its own namespace hears its peers
    only across the bridge (broadcast on 10.199.0.255); at the end every drone holds every
    peer's position, younger than the spec's bound, asked inside its namespace."""
    run_dir = tmp_path / "run"
    summary_path = tmp_path / "summary.json"
    proc = subprocess.run([*FLEET, "--out", str(run_dir), "--summary-json", str(summary_path),
                           "--netns", "--peers", "--spec", "peer_sharing", "--drones", "3",
                           "--duration", "8", "--rate", "1", "--size", "320x240",
                           "--mcts-iterations", "100", "--first-fix", "0", "--quiet"],
                          capture_output=True, text=True, timeout=140)
    print(proc.stdout[-2500:])
    assert proc.returncode == 0, proc.stderr[-3000:]
    summary = json.loads(summary_path.read_text())
    drones = ["drone1", "drone2", "drone3"]
    namespaces = summary["link"]["namespaces"]["drones"]
    assert len(set(namespaces)) == 3
    bound = summary["peers_age_bound_s"]
    assert bound == pytest.approx(37.61, abs=0.01)
    for drone in drones:
        ages = summary["peers"][drone]
        assert set(ages) == set(drones) - {drone}, ages
        assert all(age is not None and 0 <= age < bound for age in ages.values()), ages
    assert "every drone knows every peer: yes" in proc.stdout
    assert "every position within it" in proc.stdout
    for drone in drones:
        log = (run_dir / "logs" / f"{drone}.log").read_text()
        assert "shared medium: broadcast 10.199.0.255:" in log
        assert "heard from 2 peers" in log
