"""Load benchmark of the ground station (issue 6 and issue 13 acceptance).

Two rows: 10 and 50 simulated drones (``--drones 10,50``), each x 10 images/s x 30 KB on
loopback for 60 s (``--duration`` to shorten), each against a fresh station.
The station runs as its own process (``uav-ground-station run``), the senders in another
one, and this process watches the dashboard WebSocket like a browser would. Reported:
images sent / received / stored, images lost by the ground station itself (must be 0:
on loopback nothing else can lose them), dashboard update lag (generation -> WebSocket
delivery, p50/p95 must be < 1 s), CPU of the station and the senders. Prints a table
with a column per row, writes CSV and PNGs under artifacts/bench_ground/, exits non-zero
when any row misses.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import csv
import json
import os
import random
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import aiohttp

KEY = "bench-ground-fleet-key-000000"
FLEET_ID = 11
LAG_TARGET_S = 1.0


# -- sender process -------------------------------------------------------------------------
def sender_main(args: argparse.Namespace) -> int:
    """Paced senders, one UDP socket per drone, spread evenly over each frame period."""
    from companion.protocol import Encoder
    from utility_specs.message import Message

    rng = random.Random(1)
    payloads = [rng.randbytes(args.size) for _ in range(8)]
    ground = ("127.0.0.1", args.udp_port)
    drones = []
    for i in range(int(args.drones)):
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        sock.bind(("127.0.0.1", 0))
        sock.setblocking(False)
        drones.append((f"uav{i + 1:02d}", Encoder(FLEET_ID, f"uav{i + 1:02d}", KEY.encode()), sock))
    period = 1.0 / args.rate
    slot = period / int(args.drones)
    sent_images = sent_datagrams = 0
    cpu0 = time.process_time()
    t_start = time.time() + 0.2
    frame = 0
    while True:
        frame_t = t_start + frame * period
        if frame_t - t_start >= args.duration:
            break
        for i, (name, encoder, sock) in enumerate(drones):
            due = frame_t + i * slot
            delay = due - time.time()
            if delay > 0:
                time.sleep(delay)
            now = time.time()
            red = rng.random() * 0.3
            m = Message(
                sender=name,
                seq=frame + 1,
                type="image",
                t_gen=now,
                size=args.size,
                data={"red": round(red, 3), "lat": 51.1 + i * 1e-4, "lon": 17.0, "alt": 40.0},
            )
            for datagram in encoder.fragment(m, payloads[(frame + i) % 8], now):
                while True:
                    try:
                        sock.sendto(datagram, ground)
                        break
                    except BlockingIOError:  # local send buffer full: wait, never skip
                        time.sleep(0.0005)
                sent_datagrams += 1
            sent_images += 1
            # drain reports so our receive buffers do not matter
            try:
                while sock.recv(65536):
                    pass
            except BlockingIOError:
                pass
        frame += 1
    wall = time.time() - t_start
    print(
        json.dumps(
            {
                "images": sent_images,
                "datagrams": sent_datagrams,
                "wall_s": wall,
                "cpu_s": time.process_time() - cpu0,
            }
        ),
        flush=True,
    )
    return 0


# -- measuring process ----------------------------------------------------------------------
def free_port(kind: int) -> int:
    with socket.socket(socket.AF_INET, kind) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def proc_cpu_s(pid: int, *, tid: int | None = None) -> float:
    """CPU seconds of a process (all threads), or of one of its threads."""
    stat = Path(f"/proc/{pid}/stat" if tid is None else f"/proc/{pid}/task/{tid}/stat")
    fields = stat.read_text().rsplit(")", 1)[1].split()
    ticks = os.sysconf("SC_CLK_TCK")
    return (int(fields[11]) + int(fields[12])) / ticks  # utime + stime


def udp_rcvbuf_errors() -> int:
    lines = Path("/proc/net/snmp").read_text().splitlines()
    udp = [line.split() for line in lines if line.startswith("Udp:")]
    header, values = udp[0], udp[1]
    return int(values[header.index("RcvbufErrors")])


def host_cpu_s() -> float:
    """Busy CPU seconds of the whole host (every core, every process) from /proc/stat."""
    fields = Path("/proc/stat").read_text().splitlines()[0].split()[1:]
    user, nice, system, _idle, _iowait, irq, softirq, steal = (int(v) for v in fields[:8])
    return (user + nice + system + irq + softirq + steal) / os.sysconf("SC_CLK_TCK")


def percentile(values: list[float], q: float) -> float:
    if not values:
        return float("nan")
    ordered = sorted(values)
    k = (len(ordered) - 1) * q
    lo, hi = int(k), min(int(k) + 1, len(ordered) - 1)
    return ordered[lo] + (ordered[hi] - ordered[lo]) * (k - lo)


async def watch_dashboard(
    url: str, token: str, lags: list[tuple[float, float]], stop: asyncio.Event
) -> None:
    """Every image tile update: (arrival time, arrival - t_gen of the image)."""
    async with (
        aiohttp.ClientSession() as session,
        session.ws_connect(url, headers={"Authorization": f"Bearer {token}"}, max_msg_size=0) as ws,
    ):
        seen: dict[str, int] = {}
        while not stop.is_set():
            try:
                msg = await asyncio.wait_for(ws.receive(), timeout=0.5)
            except TimeoutError:
                continue
            if msg.type != aiohttp.WSMsgType.TEXT:
                break
            now = time.time()
            data = json.loads(msg.data)
            if data.get("kind") != "drone":
                continue
            image = data["drone"].get("latest_image")
            if image and seen.get(data["drone"]["drone"]) != image["seq"]:
                seen[data["drone"]["drone"]] = image["seq"]
                lags.append((now, now - image["t_gen"]))


async def get_stats(http: str, token: str) -> dict[str, Any]:
    async with (
        aiohttp.ClientSession() as session,
        session.get(f"{http}/api/stats", headers={"Authorization": f"Bearer {token}"}) as resp,
    ):
        return dict(await resp.json())


async def bench(args: argparse.Namespace) -> int:
    out_dir = Path(args.out)
    out_dir.mkdir(parents=True, exist_ok=True)
    counts = [int(n) for n in str(args.drones).split(",") if n.strip()]
    columns: list[list[tuple[str, str, str]]] = []
    verdicts: list[bool] = []
    for drones in counts:
        rows, ok = await bench_row(argparse.Namespace(**{**vars(args), "drones": drones}),
                                   out_dir)
        columns.append(rows)
        verdicts.append(ok)
    names = [name for name, _, _ in columns[0]]
    heads = [f"{n} drones" for n in counts]
    width = max(len(n) for n in names)
    print(f"\n{'measure':<{width}}" + "".join(f"  {h:>22}" for h in heads) + "  target")
    for i, name in enumerate(names):
        values = "".join(f"  {column[i][1]:>22}" for column in columns)
        print(f"{name:<{width}}{values}  {columns[0][i][2]}")
    print("".ljust(width) + "".join(f"  {'PASS' if ok else 'FAIL':>22}" for ok in verdicts))
    with open(out_dir / "bench_ground.csv", "w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow(["measure", *heads, "target"])
        for i, name in enumerate(names):
            writer.writerow([name, *(column[i][1] for column in columns), columns[0][i][2]])
    ok = all(verdicts)
    print(f"\n{'PASS' if ok else 'FAIL'} (table: {out_dir / 'bench_ground.csv'}, "
          f"plots: {out_dir / 'bench_ground_lag_*.png'})")
    return 0 if ok else 1


async def bench_row(
    args: argparse.Namespace, out_dir: Path
) -> tuple[list[tuple[str, str, str]], bool]:
    """One row: a fresh station, ``args.drones`` senders; (table rows, pass)."""
    load = os.getloadavg()[0]
    work = Path(tempfile.mkdtemp(prefix="bench-ground-"))
    udp_port, http_port = free_port(socket.SOCK_DGRAM), free_port(socket.SOCK_STREAM)
    config = work / "gs.toml"
    from ground_station.keyfiles import generate_keys

    generate_keys(work / "data" / "keys")  # the station finds them in data_dir/keys
    config.write_text(
        "[ground_station]\n"
        f'fleet_key = "{KEY}"\nfleet_id = {FLEET_ID}\ndata_dir = "data"\nmission = "bench"\n'
        f'udp_host = "127.0.0.1"\nudp_port = {udp_port}\nhttp_port = {http_port}\n'
        f"fsync = {'true' if args.fsync else 'false'}\n"
    )
    print(
        f"bench_ground: {args.drones} drones x {args.rate} images/s x {args.size} B for "
        f"{args.duration} s; station data in {work}",
        flush=True,
    )
    station = subprocess.Popen(
        [sys.executable, "-m", "ground_station.cli", "run", "--config", str(config)],
        stdout=subprocess.PIPE,
        stderr=subprocess.DEVNULL,
        text=True,
    )
    http = f"http://127.0.0.1:{http_port}"
    try:
        assert station.stdout is not None
        token = station.stdout.readline().rsplit(": ", 1)[1].strip()
        async with asyncio.timeout(20):
            while True:
                try:
                    await get_stats(http, token)
                    break
                except aiohttp.ClientError:
                    await asyncio.sleep(0.1)
        lags: list[tuple[float, float]] = []
        stop = asyncio.Event()
        watcher = asyncio.create_task(
            watch_dashboard(f"ws://127.0.0.1:{http_port}/ws", token, lags, stop)
        )
        await asyncio.sleep(0.5)
        rcvbuf0 = udp_rcvbuf_errors()
        cpu0, t0 = proc_cpu_s(station.pid), time.time()
        host0 = host_cpu_s()
        loop_cpu0 = proc_cpu_s(station.pid, tid=station.pid)  # the event loop's thread
        sender = await asyncio.create_subprocess_exec(
            sys.executable,
            __file__,
            "--sender",
            "--udp-port",
            str(udp_port),
            "--drones",
            str(args.drones),
            "--rate",
            str(args.rate),
            "--size",
            str(args.size),
            "--duration",
            str(args.duration),
            stdout=subprocess.PIPE,
        )
        progress_at = time.time() + 10
        while sender.returncode is None:
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(sender.wait(), timeout=1.0)
            if time.time() >= progress_at:
                progress_at += 10
                s = await get_stats(http, token)
                print(
                    f"  t={time.time() - t0:5.0f} s  received {s['link'].get('images', 0)}"
                    f"  stored {s['storage']['images_stored']}"
                    f"  backlog {s['storage']['backlog']}",
                    flush=True,
                )
        assert sender.stdout is not None
        sent = json.loads((await sender.stdout.read()).decode().strip().splitlines()[-1])
        cpu_station = proc_cpu_s(station.pid) - cpu0
        cpu_host = host_cpu_s() - host0
        cpu_loop = proc_cpu_s(station.pid, tid=station.pid) - loop_cpu0
        wall = time.time() - t0
        # let the station finish writing what it received (a station that cannot within
        # a minute is measured as it is: what is not stored by then counts as lost)
        with contextlib.suppress(TimeoutError):
            async with asyncio.timeout(60):
                while True:
                    s = await get_stats(http, token)
                    if (
                        s["storage"]["backlog"] == 0
                        and s["storage"]["written"] == s["storage"]["submitted"]
                    ):
                        break
                    await asyncio.sleep(0.2)
        await asyncio.sleep(0.5)
        stats = await get_stats(http, token)
        stop.set()
        await watcher
        rcvbuf_errors = udp_rcvbuf_errors() - rcvbuf0
    finally:
        station.send_signal(signal.SIGINT)
        try:
            station.wait(timeout=20)
        except subprocess.TimeoutExpired:
            station.kill()
        if not args.keep:
            shutil.rmtree(work, ignore_errors=True)
    received = int(stats["link"].get("images", 0))
    stored = int(stats["storage"]["images_stored"])
    lost = sent["images"] - stored
    # CPU the rest of the host used meanwhile (other engineers' tests, the OS): on a shared
    # machine the station gets what is left, and the verdict says so instead of hiding it
    cores = os.cpu_count() or 1
    need = cpu_station / max(received, 1) * args.drones * args.rate
    others = max(0.0, cpu_host - cpu_station - sent["cpu_s"]) / wall
    lag_values = [lag for _, lag in lags]
    p50, p95 = percentile(lag_values, 0.5), percentile(lag_values, 0.95)
    rows = [
        ("images sent", f"{sent['images']}", ""),
        ("images received", f"{received}", ""),
        ("images stored (fsync'd + indexed)", f"{stored}", ""),
        ("lost by the ground station", f"{lost}", "must be 0"),
        (
            "  of which incomplete/evicted",
            f"{stats['drops'].get('incomplete', 0)}/{stats['drops'].get('evicted', 0)}",
            "",
        ),
        ("  UDP receive-buffer drops (host-wide)", f"{rcvbuf_errors}", ""),
        ("  storage errors", f"{stats['storage']['errors']}", ""),
        ("  not stored (visible, never reported)", f"{stats['storage'].get('not_stored', 0)}",
         ""),
        ("  refused by back-pressure", f"{stats['storage'].get('refused', 0)}", ""),
        ("receiver reports sent", f"{stats['link'].get('reports_sent', 0)}", ""),
        ("datagrams sent", f"{sent['datagrams']}", ""),
        ("goodput received", f"{received * args.size / wall / 1e6:.2f} MB/s", ""),
        ("dashboard lag p50", f"{p50 * 1000:.0f} ms", f"< {LAG_TARGET_S * 1000:.0f} ms"),
        ("dashboard lag p95", f"{p95 * 1000:.0f} ms", f"< {LAG_TARGET_S * 1000:.0f} ms"),
        ("dashboard updates seen", f"{len(lags)}", ""),
        ("station CPU", f"{100 * cpu_station / wall:.0f} % of one core", ""),
        ("  of which the event loop's thread", f"{100 * cpu_loop / wall:.0f} % of one core",
         ""),
        # what the station spent per image it received, and so what the whole row needs:
        # above what the station got, the kernel drops datagrams (receive-buffer drops)
        ("station CPU per image received",
         f"{1000 * cpu_station / max(received, 1):.2f} ms", ""),
        ("  event loop CPU per image", f"{1000 * cpu_loop / max(received, 1):.2f} ms", ""),
        ("  station CPU the row needs at that cost",
         f"{cpu_station / max(received, 1) * args.drones * args.rate:.2f} cores", ""),
        ("UDP receive buffer granted", f"{stats.get('udp_rcvbuf_bytes', 0) >> 20} MiB", ""),
        ("senders CPU", f"{100 * sent['cpu_s'] / sent['wall_s']:.0f} % of one core", ""),
        ("other processes' CPU during the row", f"{others:.2f} of {cores} cores", ""),
        ("machine", f"{os.cpu_count()} cores, fsync={'on' if args.fsync else 'off'}", ""),
        ("load average before / after", f"{load:.1f} / {os.getloadavg()[0]:.1f}", ""),
    ]
    plot(lags, t0, out_dir / f"bench_ground_lag_{args.drones}.png")
    ok = lost == 0 and p95 < LAG_TARGET_S and p50 < LAG_TARGET_S and len(lags) > 0
    print(f"  {args.drones} drones: {'PASS' if ok else 'FAIL'}", flush=True)
    if not ok:
        for reason in why_failed(lost=lost, sent=sent["images"], received=received,
                                 stats=stats, p95=p95, need=need,
                                 got=cpu_station / wall, others=others, cores=cores):
            print(f"    - {reason}", flush=True)
    return rows, ok


def why_failed(
    *, lost: int, sent: int, received: int, stats: dict[str, Any], p95: float, need: float,
    got: float, others: float, cores: int,
) -> list[str]:
    """Where the row's images went, and whether the station or the host was short of CPU:
    the verdict stays FAIL either way, but says which it was."""
    reasons = []
    if lost:
        refused = int(stats["storage"].get("refused", 0))
        not_stored = int(stats["storage"].get("not_stored", 0)) - refused
        reasons.append(
            f"{lost} images not stored: {sent - received} never read off the socket (kernel "
            f"buffer full or fragments lost), {refused} refused by storage back-pressure, "
            f"{max(0, not_stored)} failed to store")
    if p95 >= LAG_TARGET_S:
        reasons.append(f"dashboard lag p95 {p95 * 1000:.0f} ms >= {LAG_TARGET_S * 1000:.0f} ms")
    if need > got * 1.05:
        reasons.append(
            f"the station needs {need:.2f} cores at its measured cost per image and got "
            f"{got:.2f}; other processes used {others:.2f} of the {cores} cores meanwhile"
            + (" (the host was saturated: rerun on a quiet machine)"
               if others + got + 0.25 >= cores else ""))
    return reasons


def plot(lags: list[tuple[float, float]], t0: float, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(11, 3.8))
    ax1.plot([t - t0 for t, _ in lags], [lag * 1000 for _, lag in lags], ".", ms=2)
    ax1.axhline(LAG_TARGET_S * 1000, color="red", lw=1, label="target")
    ax1.set(xlabel="time (s)", ylabel="dashboard lag (ms)", title="lag of each tile update")
    ax1.legend()
    ax2.hist([lag * 1000 for _, lag in lags], bins=60)
    ax2.set(xlabel="dashboard lag (ms)", ylabel="updates", title="distribution")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--duration", type=float, default=60.0, help="seconds of load")
    parser.add_argument("--drones", default="10,50",
                        help="drone counts, one row each (comma-separated)")
    parser.add_argument("--rate", type=float, default=10.0, help="images per second per drone")
    parser.add_argument("--size", type=int, default=30_000, help="image bytes")
    parser.add_argument("--no-fsync", dest="fsync", action="store_false")
    parser.add_argument("--out", default="artifacts/bench_ground")
    parser.add_argument("--keep", action="store_true", help="keep the station's data folder")
    parser.add_argument("--sender", action="store_true", help=argparse.SUPPRESS)
    parser.add_argument("--udp-port", type=int, help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.sender:
        return sender_main(args)
    return asyncio.run(bench(args))


if __name__ == "__main__":
    raise SystemExit(main())
