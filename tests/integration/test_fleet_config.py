"""The fleet launcher's pure parts: run-folder configs, key file, options, progress, counters.

The configs are read back by the real parsers of the companion and the ground station, so a
key either of them would reject fails here, not 30 s into an end-to-end run.
"""

from __future__ import annotations

import json
import stat
import tomllib
from pathlib import Path

import pytest

from companion.config import load_config as load_companion_config
from companion.protocol.signing import fleet_key_text
from ground_station.config import load_config as load_gs_config
from sitl.fleet import (
    Background,
    LogTail,
    StationTail,
    format_summary,
    make_plan,
    parse_args,
    parse_background,
    progress_line,
    summarize,
)
from sitl.fleet_config import mission_spec_path, toml_value, write_fleet_key, write_run_configs
from sitl.scenes import scene_path


def _plan(tmp_path: Path, *extra: str):  # type: ignore[no-untyped-def]
    args = parse_args(["--drones", "3", "--goodput", "12000", "--window", "2.5", *extra])
    return make_plan(args, tmp_path / "run")


def test_configs_are_accepted_by_the_companion_and_the_ground_station(tmp_path: Path) -> None:
    plan = _plan(tmp_path, "--rate", "2", "--size", "320x240", "--alpha", "7")
    write_run_configs(plan)
    key = fleet_key_text(plan.key_path.read_bytes(), "fleet.key")
    assert len(key) >= 32
    gs = load_gs_config(plan.gs_config_path)
    assert gs.fleet_key == key and gs.udp_port == plan.gs_udp_port
    assert gs.http_port == plan.gs_http_port and gs.data_dir == plan.gs_data_dir
    assert gs.spec == mission_spec_path("image_streaming") and gs.alpha == 7.0
    assert gs.scene == scene_path("demo").resolve()  # the dashboard map draws the flown scene
    ids = set()
    for drone in plan.drones:
        cfg = load_companion_config(drone.config_path)
        ids.add(cfg.drone_id)
        assert cfg.ground_station.fleet_key == key
        # through the shaped relay, which forwards to the station
        assert plan.relay_port not in (None, plan.gs_udp_port)
        assert (cfg.ground_station.host, cfg.ground_station.port) == ("127.0.0.1",
                                                                      plan.relay_port)
        assert cfg.telemetry.status_period_s == 1.0  # the heartbeat
        assert cfg.mavlink.url == f"udpin:127.0.0.1:{drone.mavlink_port}"
        assert (cfg.camera.source, cfg.camera.width, cfg.camera.rate_hz) == ("synthetic", 320,
                                                                             2.0)
        assert cfg.camera.options["scene"] == "demo"
        assert cfg.constraint.name == "constant"
        assert dict(cfg.constraint.params) == {"limit_bytes_per_s": 12000.0, "window_s": 2.5}
        assert cfg.mission.log == str(drone.log_path)
        assert cfg.middleware["alpha"] == 7.0
    assert ids == {"drone1", "drone2", "drone3"}
    assert len({d.mavlink_port for d in plan.drones}) == 3
    assert gs.link_lost_s == 5.0
    direct = _plan(tmp_path / "direct", "--relay-rate", "0")
    write_run_configs(direct)
    cfg = load_companion_config(direct.drones[0].config_path)
    assert direct.relay_port is None and cfg.ground_station.port == direct.gs_udp_port


def test_fleet_key_is_fresh_and_private(tmp_path: Path) -> None:
    path = tmp_path / "k" / "fleet.key"
    first = write_fleet_key(path)
    assert stat.S_IMODE(path.stat().st_mode) == 0o600
    second = write_fleet_key(path)
    assert first != second and path.read_bytes().strip() == second
    assert stat.S_IMODE(path.stat().st_mode) == 0o600


def test_toml_values_round_trip() -> None:
    table = {"s": 'a "quoted" \\ path', "i": 3, "f": 0.1, "b": True, "l": [1, 2],
             "t": {"x": 1.5, "y": "z"}}
    text = "\n".join(f"{k} = {toml_value(v)}" for k, v in table.items())
    assert tomllib.loads(text) == table
    with pytest.raises(ValueError):
        toml_value(float("nan"))


def test_options() -> None:
    args = parse_args([])
    assert (args.drones, args.scene, args.duration, args.policy) == (4, "demo", 0.0, "mcts")
    # issue 12: by default the fleet talks through the shaped relay, under the adaptive
    # constraint, with a background step at mid-mission (60 s when open-ended)
    assert args.constraint == "adaptive" and (args.width, args.height) == (640, 480)
    assert args.relay and (args.relay_rate, args.relay_queue) == (400_000.0, 20_000)
    assert args.background == Background(160_000.0, 60.0, None)
    assert parse_args(["--duration", "120"]).background == Background(160_000.0, 60.0, None)
    assert parse_args(["--background", "off"]).background is None
    assert parse_args(["--goodput", "9000"]).constraint == "constant"  # as before
    plain = parse_args(["--relay-rate", "0"])
    assert (plain.relay, plain.constraint, plain.background) == (False, "constant", None)
    assert parse_args(["--netns"]).constraint == "adaptive"
    assert not parse_args(["--netns"]).relay
    for bad in (["--drones", "0"], ["--duration", "-1"], ["--size", "big"],
                ["--relay-rate", "0", "--background", "1e6"], ["--relay-rate", "-1"],
                ["--drop-probability", "2"]):
        with pytest.raises(SystemExit):
            parse_args(bad)
    assert parse_background("2e6") == Background(2e6, 0.0, None)
    assert parse_background("2e6@20+15") == Background(2e6, 20.0, 15.0)
    with pytest.raises(ValueError):
        parse_background("fast@now")


def test_scene_errors_stop_before_anything_starts(tmp_path: Path) -> None:
    bad = tmp_path / "bad.toml"
    bad.write_text("name = 3\n")
    with pytest.raises(ValueError, match=r"bad\.toml"):
        make_plan(parse_args(["--scene", str(bad)]), tmp_path / "run")


def _record(sender: str, seq: int, t_gen: float, *, sent: bool, rcv: float | None = None,
            size: int = 1000, red: float = 0.0) -> dict[str, object]:
    return {"sender": sender, "receiver": "gs" if rcv else None, "seq": seq, "type": "image",
            "t_gen": t_gen, "t_sent": t_gen + 0.01 if sent else None, "t_rcv": rcv,
            "size": size, "data": {"red": red}, "version": 0 if sent else None,
            "versions": [{"name": "full", "size": 4000, "quality": 1.0},
                         {"name": "quarter", "size": size, "quality": 0.25}]}


def test_log_tail_counts_complete_lines_only(tmp_path: Path) -> None:
    path = tmp_path / "log.jsonl"
    tail = LogTail(path)
    tail.poll()  # no file yet
    assert (tail.generated, tail.sent) == (0, 0)
    lines = [json.dumps(_record("d", i, 10.0 + i, sent=i % 2 == 0), separators=(",", ":"))
             for i in range(5)]
    path.write_text("\n".join(lines[:3]) + "\n" + lines[3][:20])  # a half-written line
    tail.poll()
    assert (tail.generated, tail.sent) == (3, 2)
    path.write_text("\n".join(lines) + "\n" + json.dumps({"mission": {"t_end": 20.0}}) + "\n")
    tail.poll()
    assert (tail.generated, tail.sent) == (5, 3)


def test_summary_counts_the_mission_window(tmp_path: Path) -> None:
    plan = _plan(tmp_path)
    write_run_configs(plan)
    t0 = 1_700_000_000.0
    d1, d2, d3 = (d.drone_id for d in plan.drones)
    own = {d1: [_record(d1, i, t0 - 1 + i, sent=i < 8, red=0.5) for i in range(12)],
           d2: [_record(d2, i, t0 + i, sent=i < 2) for i in range(10)], d3: []}
    for drone in plan.drones:
        drone.log_path.parent.mkdir(parents=True, exist_ok=True)
        drone.log_path.write_text("".join(json.dumps(r) + "\n" for r in own[drone.drone_id]))
    got = [_record(d1, i, t0 - 1 + i, sent=True, rcv=t0 - 1 + i + 0.05) for i in range(8)]
    got += [_record(d2, 0, t0, sent=True, rcv=t0 + 0.25)]
    # a better version of d1's seq 3 arrives later: one more copy, not one more image
    got += [_record(d1, 3, t0 + 2, sent=True, rcv=t0 + 2.5, size=4000)]
    plan.gs_log_path.parent.mkdir(parents=True)
    plan.gs_log_path.write_text("".join(json.dumps(r) + "\n" for r in got))
    s = summarize(plan, t_start=t0, t_end=t0 + 10.0, policy="mcts")
    a, b, c = (s["drones"][d] for d in (d1, d2, d3))
    # d1: seq 0 was generated before the start; seqs 1..11 in [t0, t0 + 10]: 11 generated,
    # 7 sent and received (seq 1..7), one received before the window.
    assert (a["generated"], a["sent"], a["received"], a["received_total"]) == (11, 7, 7, 8)
    assert a["fps"] == pytest.approx(0.7) and a["latency_mean_s"] == pytest.approx(0.05)
    assert a["mean_red"] == pytest.approx(0.5)
    assert (b["generated"], b["sent"], b["received"]) == (10, 2, 1)
    assert b["latency_mean_s"] == pytest.approx(0.25)
    assert (c["generated"], c["received"], c["latency_mean_s"]) == (0, 0, None)
    assert a["bytes_received"] == 7 * 1000 + 4000
    assert s["bytes_received"] == 8 * 1000 + 4000 and s["bytes_generated"] == (11 + 10) * 4000
    assert s["bytes_generated_mean_version"] == (11 + 10) * (4000 + 1000) / 2
    text = format_summary(s)
    assert d1 in text and "data:" in text


def test_progress_line_shows_each_drone(tmp_path: Path) -> None:
    plan = _plan(tmp_path)
    t0 = 1_700_000_000.0
    tails = {d.drone_id: LogTail(d.log_path, generated=10 * d.index, sent=d.index,
                                 sent_keys={(i, t0 + i) for i in range(d.index)})
             for d in plan.drones}
    gs_log = tmp_path / "gs.jsonl"
    got = [_record("drone2", i, t0 + i, sent=True, rcv=t0 + i + 0.042) for i in range(10)]
    got.append({**_record("drone2", 99, t0, sent=True, rcv=t0 + 9.5), "type": "position"})
    gs_log.write_text("".join(json.dumps(r) + "\n" for r in got))
    station = StationTail(gs_log, window_s=5.0)
    station.poll()
    line = progress_line(12.0, plan.drones, tails, station, now=t0 + 9.5)
    # drone2: 10 images received, those of t_rcv in [t0 + 4.5, t0 + 9.5]: 5 in 5 s; of the
    # 10 its companion's log shows one sent so far, so one counts as received (it said r10
    # next to s1: more received than sent, audit 13)
    assert line.startswith("[   12 s] drone1 g0 s0 r0 0.0/s -")
    assert "drone2 g10 s1 r1 1.0/s 42ms" in line and "drone3 g20 s2 r0" in line
    tails["drone2"].sent = 10  # its log catches up
    tails["drone2"].sent_keys |= {(i, t0 + i) for i in range(10)}
    assert "drone2 g10 s10 r10 " in progress_line(12.0, plan.drones, tails, station,
                                                  now=t0 + 9.5)


def test_random_baseline_drops_at_its_rate_and_picks_any_version(tmp_path: Path) -> None:
    """``--policy random`` is the companion's ``random_drop`` policy, read from the config
    the fleet writes: it drops at its rate, keeps any version, and always sends status."""
    import numpy as np

    from companion.app import build_decider
    from companion.middleware import ConstantConstraint, DeciderSetup, RandomDrop, make_decider
    from utility_specs.files import builtin_spec
    from utility_specs.message import Message, Version

    plan = _plan(tmp_path, "--policy", "random", "--drop-probability", "0.75", "--seed", "7")
    write_run_configs(plan)
    config = load_companion_config(plan.drones[1].config_path)
    assert dict(config.middleware) == {"seed": 8, "policy": "random_drop",
                                       "drop_probability": 0.75, "any_version": True}
    built = build_decider(config)
    assert isinstance(built, RandomDrop) and (built.p, built.any_version) == (0.75, True)
    assert built.always_send == {"status"}
    mcts = _plan(tmp_path / "mcts")
    write_run_configs(mcts)
    assert dict(load_companion_config(mcts.drones[0].config_path).middleware) == {
        "seed": 0, "fleet_size": 3}

    versions = tuple(Version(name=n, size=s, quality=q)
                     for n, s, q in (("full", 4000, 1.0), ("half", 1500, 0.5),
                                     ("quarter", 600, 0.25)))
    image = Message(sender="d", seq=1, type="image", t_gen=0.0, size=4000, data={"red": 0.0},
                    versions=versions, version=0)
    status = Message(sender="d", seq=2, type="status", t_gen=0.0, size=50, data={})

    def random_drop(p: float, seed: int) -> RandomDrop:
        setup = DeciderSetup(spec=builtin_spec("image_streaming"), agent="d",
                             constraint=ConstantConstraint(limit_bytes_per_s=1e4),
                             rng=np.random.default_rng(seed))
        policy = make_decider("random_drop", setup, drop_probability=p, any_version=True)
        assert isinstance(policy, RandomDrop)
        return policy

    policy = random_drop(0.75, 1)
    decisions = [policy.decide(image, 0.0) for _ in range(4000)]
    sent = [d for d in decisions if d.send]
    assert len(sent) / 4000 == pytest.approx(0.25, abs=0.03)
    counts = [sum(d.version == v for d in sent) for v in range(3)]
    assert all(c / len(sent) == pytest.approx(1 / 3, abs=0.06) for c in counts)
    assert all(d.version is None for d in decisions if not d.send)
    never = random_drop(1.0, 2)
    assert not never.decide(image, 0.0).send
    assert never.decide(status, 0.0).send  # the station must still hear the drone
    with pytest.raises(ValueError):
        random_drop(1.5, 0)


def test_first_fix_option() -> None:
    """The fleet's vehicles boot without a fix for a short while (issue 17); bad values stop
    the launcher with a usage error."""
    assert parse_args([]).first_fix == 2.0
    assert parse_args(["--first-fix", "0"]).first_fix == 0.0
    for bad in (["--first-fix", "-1"], ["--first-fix", "nan"]):
        with pytest.raises(SystemExit):
            parse_args(bad)
