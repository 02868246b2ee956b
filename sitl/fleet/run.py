"""One fleet run: bring the processes up in order, start the mission, watch, stop, summarise."""

from __future__ import annotations

import argparse
import json
import shutil
import signal
import sys
import time
import urllib.error
from collections.abc import Callable
from pathlib import Path
from typing import IO, Any

from sitl.fleet.link import relay_argv, relay_description, relay_link
from sitl.fleet.live import PROGRESS_LEGEND, GroundStationApi, LogTail, StationTail, progress_line
from sitl.fleet.netns import FleetNetns, Loopback
from sitl.fleet.plan import make_plan
from sitl.fleet.processes import (
    Child,
    FleetError,
    Processes,
    Stop,
    Stopped,
    signal_group,
    tool,
    wait,
)
from sitl.fleet.summary import (
    evaluate_utility,
    finite,
    format_summary,
    summarize,
    unused_note,
    write_report_png,
)
from sitl.fleet.warmup import wait_for_warm_up
from sitl.fleet_config import DroneSlot, mavlink_host, write_run_configs


def _try(call: Callable[[], Any]) -> Any:
    try:
        return call()
    except (OSError, urllib.error.URLError, ValueError):
        return None


def run(args: argparse.Namespace, *, out: IO[str] = sys.stdout) -> int:
    run_dir = (args.out or Path("out") / "fleet" / time.strftime("%Y%m%d-%H%M%S")).resolve()
    netns = None
    if args.netns:
        netns = FleetNetns(drones=args.drones, rate_bit_s=args.link_rate,
                           delay_s=args.link_delay / 1000.0, loss=args.link_loss / 100.0)
    plan = make_plan(args, run_dir, netns=netns is not None)
    write_run_configs(plan)
    from ground_station.token import ensure_token, login_code

    token, _ = ensure_token(plan.gs_data_dir / "token")
    procs = Processes(plan.logs_dir)
    stop = Stop()
    previous = {sig: signal.signal(sig, stop)
                for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)}
    tty = out.isatty() and not args.quiet
    t_start = t_end = None
    companions: list[Child] = []
    vehicles: list[Child] = []
    station: list[Child] = []
    failure: str | None = None
    stopped_early = False
    base_url = f"http://127.0.0.1:{plan.gs_http_port}"
    link_info: dict[str, Any] | None = None
    peers_known: dict[str, Any] | None = None
    relay_stats = run_dir / "relay.json"
    relay_signalled = False
    where: FleetNetns | Loopback = netns or Loopback()
    try:
        if netns is not None:
            netns.open()
            base_url = netns.forward_http(plan.gs_http_port)
        api = GroundStationApi(base_url, token)
        print(f"run folder: {run_dir}", file=out)
        print(f"dashboard:  {base_url}/?login={login_code(token, now=time.time())}", file=out)
        print(f"token:      {token}   (also: uav-ground-station token --data-dir "
              f"{plan.gs_data_dir})", file=out)
        if args.relay:
            print(f"link:       {relay_description(args)}", file=out)
        elif netns is None:
            print("link:       loopback, unshaped (no relay: --relay-rate 0)", file=out)
        params = dict(plan.constraint_params)  # none: the companion's defaults ("adaptive {}")
        print(f"constraint: {plan.constraint} {params if params else '(defaults)'}"
              f"{unused_note(args.policy)}", file=out)
        if netns is not None:
            print(f"link:       {netns.medium.describe()}", file=out)
            if netns.medium.netem is False:  # said on stderr too, where warnings go
                print(f"uav-sitl fleet: WARNING: link {netns.medium.impairment_note}",
                      file=sys.stderr)
        out.flush()

        station.append(procs.start("ground_station", where.wrap_gs(
            [*tool("uav-ground-station", "ground_station.cli"), "run",
             "--config", str(plan.gs_config_path)])))
        relay: list[Child] = []
        if args.relay:
            relay.append(procs.start("relay", relay_argv(args, plan, relay_stats)))
        ready_file = run_dir / "vehicles.json"
        vargv = [*tool("uav-sitl", "sitl.cli"), "vehicle", "--count", str(args.drones),
                 "--port", "0", "--host", plan.drone_bind_host, "--scene", plan.scene,
                 "--pattern", args.pattern, "--autostart", "--speedup", str(args.speedup),
                 "--flavour", args.flavour, "--seed", str(args.seed),
                 "--first-fix", str(args.first_fix),
                 "--ready-file", str(ready_file)]
        if plan.peers_medium is not None:
            from sitl.fleet_peers import vehicle_args
            vargv += vehicle_args(args.flavour)
        for slot in plan.drones:
            vargv += ["--out", f"{mavlink_host(plan, slot)}:{slot.mavlink_port}"]
        vehicles.append(procs.start("vehicles", where.wrap_vehicles(vargv)))
        wait(stop, "the vehicles", args.ready_timeout, ready_file.exists, vehicles)
        wait(stop, "the ground station's API", args.ready_timeout,
              lambda: _try(lambda: api.get("/api/stats")) is not None, station)
        for slot in plan.drones:
            companions.append(procs.start(slot.drone_id, where.wrap_drone(
                slot.index, _companion_argv(slot))))
        print(f"waiting for {args.drones} drone(s) to be heard...", file=out)
        out.flush()

        def all_heard() -> bool:
            fleet = _try(lambda: api.get("/api/fleet")) or {}
            heard = {d.get("drone") for d in fleet.get("drones", [])}
            return all(s.drone_id in heard for s in plan.drones)

        wait(stop, f"{args.drones} drones to be heard", args.ready_timeout, all_heard,
              [*station, *vehicles, *companions])
        cold = wait_for_warm_up(lambda: _try(lambda: api.get("/api/fleet")),
                                [s.drone_id for s in plan.drones], stop=stop,
                                timeout_s=args.warm_up_timeout, out=out,
                                watch=[*station, *vehicles, *companions])
        if cold:  # they send statuses only until warm; the others need not wait for them
            print(f"uav-sitl fleet: WARNING: {', '.join(cold)} still warming up after "
                  f"{args.warm_up_timeout:g} s (optimiser compiling); starting the mission "
                  "anyway: they send images once warm", file=sys.stderr)
        t_exec = time.time() + args.start_delay
        if _try(lambda: api.post("/api/mission/start", {"t_exec": t_exec})) is None:
            raise FleetError(f"the ground station did not take the start command; see "
                             f"{station[0].log_path}")
        t_start = t_exec
        print(f"mission started at {time.strftime('%H:%M:%S', time.localtime(t_start))} "
              f"({args.policy}); {'Ctrl-C to stop' if args.duration == 0 else ''}"
              f"{'' if args.duration == 0 else f'running {args.duration:g} s'}", file=out)
        if not args.quiet:
            print(PROGRESS_LEGEND, file=out)
        out.flush()
        if netns is not None and args.background is not None:
            netns.schedule_background(args.background, t_start)
        tails = {s.drone_id: LogTail(s.log_path) for s in plan.drones}
        station_tail = StationTail(plan.gs_log_path)
        last_plain = 0.0
        while True:
            now = time.time()
            if netns is not None:
                netns.tick(now)
            if relay and not relay_signalled and now >= t_start:
                signal_group(relay[0].proc, signal.SIGUSR1)  # the background's origin
                relay_signalled = True
            if args.duration and now >= t_start + args.duration:
                break
            dead = [c for c in (*station, *vehicles, *companions, *relay) if not c.alive()]
            if dead:
                failure = (f"{dead[0].name} exited ({dead[0].proc.returncode}); its log "
                           f"({dead[0].log_path}) ends with:\n{dead[0].tail()}")
                break
            for tail in tails.values():
                tail.poll()
            station_tail.poll()
            line = progress_line(max(0.0, now - t_start), plan.drones, tails, station_tail, now)
            if tty:
                width = shutil.get_terminal_size((160, 20)).columns
                out.write("\r" + line[: width - 1].ljust(width - 1))
                out.flush()
            elif not args.quiet and now - last_plain >= 10.0:
                print(line, file=out)
                out.flush()
                last_plain = now
            if stop.sleep(1.0):
                break
        t_end = time.time()
        if tty:
            out.write("\n")
        if plan.peers_medium is not None:  # who knows whom, before stopping
            from sitl.fleet_peers import poll_peers
            peers_known = poll_peers(plan.peers_http_ports, namespaces=None if netns is None
                                     else {s.drone_id: netns.medium.ns_drones[s.index]
                                           for s in plan.drones})
        _try(lambda: api.post("/api/mission/end", {"t_exec": t_end}))
    except Stopped as exc:  # Ctrl-C while it came up: said, and a clean exit
        failure = str(exc)
        stopped_early = True
    except FleetError as exc:
        failure = str(exc)
    finally:
        print("stopping: companions, vehicles, ground station...", file=out)
        out.flush()
        procs.stop(companions, timeout_s=15.0)
        procs.stop(vehicles, timeout_s=5.0)
        time.sleep(0.5)  # the last datagrams reach the station before it stops
        procs.stop(station, timeout_s=15.0)
        procs.stop_all(timeout_s=5.0)
        if args.relay:
            link_info = relay_link(args, relay_stats)
        if netns is not None:
            if netns.medium.namespaces:
                link_info = netns.describe()
            netns.close()
        for sig, handler in previous.items():
            signal.signal(sig, handler)
    if t_start is None or t_end is None or t_end <= t_start:
        print(f"uav-sitl fleet: {failure or 'stopped before the mission started'}"
              f"{'; no mission ran' if stopped_early else ''}", file=sys.stderr)
        return 0 if stopped_early else 1
    utility = evaluate_utility([plan.gs_log_path, *(s.log_path for s in plan.drones)],
                               spec=plan.spec_path, t_start=t_start, t_end=t_end)
    summary = summarize(plan, t_start=t_start, t_end=t_end, policy=args.policy, utility=utility)
    summary["drop_probability"] = args.drop_probability if args.policy == "random" else None
    summary["constraint"] = {"name": plan.constraint, **dict(plan.constraint_params)}
    summary["exit_codes"] = {c.name: c.proc.returncode for c in procs.children}
    summary["failure"] = failure
    summary["dashboard"] = f"{base_url}/"
    summary["link"] = link_info
    summary["peers"] = peers_known
    if peers_known is not None:
        from sitl.fleet_peers import position_age_bound
        summary["peers_age_bound_s"] = position_age_bound(plan.spec_path)
    summary["report"] = write_report_png(plan)
    text = json.dumps(finite(summary), indent=2, sort_keys=True, allow_nan=False)
    (run_dir / "summary.json").write_text(text + "\n", encoding="utf-8")
    print(format_summary(summary), file=out)
    if args.summary_json is not None:  # checked at start; a copy that still fails is a note
        try:
            args.summary_json.parent.mkdir(parents=True, exist_ok=True)
            args.summary_json.write_text(text + "\n", encoding="utf-8")
        except OSError as exc:
            print(f"uav-sitl fleet: warning: cannot write --summary-json {args.summary_json}"
                  f" ({exc.strerror or exc}); the summary is in {run_dir / 'summary.json'}",
                  file=sys.stderr)
    if failure:
        print(f"uav-sitl fleet: {failure}", file=sys.stderr)
        return 1
    return 0


def _companion_argv(slot: DroneSlot) -> list[str]:
    """``uav-companion run``: its ``[middleware] policy`` (written into the drone's config
    from ``--policy``) decides what goes out, so every policy runs the same app."""
    return [*tool("uav-companion", "companion.cli"), "--log-format", "text", "run",
            "--config", str(slot.config_path)]
