"""Sans-I/O pieces: receiver reports, fleet view, image utility, broadcaster, config."""

from __future__ import annotations

import asyncio
from dataclasses import replace
from pathlib import Path

import pytest
from hypothesis import given
from hypothesis import strategies as st

from ground_station.broadcast import Broadcaster
from ground_station.config import ConfigError, GroundConfig, load_config
from ground_station.fleet import RATE_WINDOW_S, FleetView
from ground_station.reports import ReportScheduler
from ground_station.utility import ImageUtility, image_utility_from_spec
from utility_specs.message import Message, Version

T0 = 1_700_000_000.0
SPECS = Path(__file__).resolve().parents[2] / "utility_specs" / "missions"


def msg(
    seq: int, *, t_gen: float, t_rcv: float, size: int = 100, sender: str = "d1", **data: object
) -> Message:
    return Message(
        sender=sender,
        seq=seq,
        type="image",
        t_gen=t_gen,
        t_sent=t_gen,
        t_rcv=t_rcv,
        size=size,
        data=data,
        receiver="gs",
    )


# -- reports -------------------------------------------------------------------------------
def test_report_schedule_repeat_and_echo() -> None:
    rs = ReportScheduler(interval_s=0.25, repeat=2, now=T0)
    assert rs.get_timer() == T0 + 0.25
    rs.on_message(msg(1, t_gen=T0, t_rcv=T0 + 0.1), t_rcv=T0 + 0.1)
    rs.on_datagram("d1", t_sent=T0 + 0.05, t_rcv=T0 + 0.1)
    rs.on_datagram("d1", t_sent=T0 + 0.01, t_rcv=T0 + 0.12)  # older datagram: ignored
    assert rs.due(now=T0 + 0.2) is None
    first = rs.due(now=T0 + 0.25)
    assert first is not None
    assert [(e.sender, e.seq, e.t_rcv) for e in first.entries] == [("d1", 1, T0 + 0.1)]
    assert [(e.sender, e.t_sent, e.t_rcv) for e in first.echoes] == [("d1", T0 + 0.05, T0 + 0.1)]
    assert rs.get_timer() == T0 + 0.5
    rs.on_message(msg(2, t_gen=T0, t_rcv=T0 + 0.3), t_rcv=T0 + 0.3)
    second = rs.due(now=T0 + 0.5)
    assert second is not None and [e.seq for e in second.entries] == [1, 2]
    third = rs.due(now=T0 + 0.75)
    assert third is not None and [e.seq for e in third.entries] == [2]
    # a stall of 1 s skips missed periods instead of bursting
    assert rs.due(now=T0 + 1.8) is not None
    assert rs.get_timer() == pytest.approx(T0 + 2.0)


# -- fleet view ----------------------------------------------------------------------------
def test_fps_of_a_drone_with_an_image_every_few_seconds_is_steady() -> None:
    """One image every 5 s (the demo's narrow link): the tile says 0.2 between images, not
    0.0 / 0.2 by turns; a drone heard for less than the window is counted over its time."""
    fv = FleetView(high_utility=3.0, link_lost_s=2.0)
    for k in range(13):
        t = T0 + 5.0 * k
        fv.on_message(msg(k, t_gen=t - 0.2, t_rcv=t, size=300), now=t, utility=1.0)
    readings = [fv.drone_json(fv.drones["d1"], now=T0 + 60.0 + dt)["fps"]
                for dt in (0.5, 1.5, 2.5, 3.5, 4.5)]
    assert readings == pytest.approx([0.2] * 5)
    early = FleetView(high_utility=3.0, link_lost_s=2.0)
    for k in range(3):
        early.on_message(msg(k, t_gen=T0 + 5.0 * k, t_rcv=T0 + 5.0 * k, size=300),
                         now=T0 + 5.0 * k, utility=1.0)
    assert early.drone_json(early.drones["d1"], now=T0 + 14.0)["fps"] == pytest.approx(3 / 14)


def test_fleet_rates_share_latency_and_link_loss() -> None:
    fv = FleetView(high_utility=3.0, link_lost_s=2.0)
    for k in range(10):
        t = T0 + 0.1 * k
        fv.on_message(msg(k, t_gen=t - 0.2, t_rcv=t, size=300), now=t, utility=1.0)
        fv.on_message(msg(k, t_gen=t - 0.2, t_rcv=t, size=100, sender="d2"), now=t, utility=6.0)
    now = T0 + 1.0
    d1 = fv.drone_json(fv.drones["d1"], now=now)
    d2 = fv.drone_json(fv.drones["d2"], now=now)
    assert d1["fps"] == pytest.approx(10 / RATE_WINDOW_S)
    assert d1["goodput_share"] == pytest.approx(0.75)
    assert d2["goodput_share"] == pytest.approx(0.25)
    assert d1["latency_s"] == pytest.approx(0.2)
    assert d2["latest_image"]["high"] is True and d1["latest_image"]["high"] is False
    fv.take_new_alerts()
    fv.tick(now=T0 + 2.5)
    assert fv.take_new_alerts() == []
    fv.tick(now=T0 + 3.0)
    alerts = fv.take_new_alerts()
    assert [(a.kind, a.drone, a.level) for a in alerts] == [
        ("link", "d1", "error"),
        ("link", "d2", "error"),
    ]
    fv.heard("d1", now=T0 + 3.1)
    assert [a.text for a in fv.take_new_alerts()] == ["link back"]
    assert fv.drones["d1"].link_lost is False and fv.drones["d2"].link_lost is True


def test_fleet_applies_telemetry_fields_and_local_coordinates() -> None:
    fv = FleetView(high_utility=3.0, link_lost_s=2.0)
    fv.on_message(msg(1, t_gen=T0, t_rcv=T0, lat=51.0, lon=17.0, level=0.5), now=T0)
    fv.on_message(
        msg(
            2,
            t_gen=T0,
            t_rcv=T0,
            sender="d2",
            lat=51.001,
            lon=17.0,
            mode="AUTO",
            armed=True,
            gps_fix=3,
            xi_bytes_per_s=5e4,
            delta_s=0.1,
            statustext="EKF variance",
            severity=4,
        ),
        now=T0,
    )
    d1, d2 = fv.drones["d1"], fv.drones["d2"]
    assert (d1.x_m, d1.y_m, d1.battery) == (0.0, 0.0, 0.5)
    assert d2.y_m == pytest.approx(111.19, abs=0.01) and d2.x_m == pytest.approx(0.0)
    assert (d2.mode, d2.armed, d2.gps_fix, d2.xi_bytes_per_s, d2.delta_s) == (
        "AUTO",
        True,
        3,
        5e4,
        0.1,
    )
    [alert] = fv.take_new_alerts()
    assert (alert.kind, alert.level, alert.text) == ("statustext", "warning", "EKF variance")


def test_drop_alerts_are_rate_limited_to_powers_of_ten() -> None:
    fv = FleetView(high_utility=3.0, link_lost_s=2.0)
    for _ in range(120):
        fv.on_drop("bad_tag", now=T0)
    assert fv.drops["bad_tag"] == 120
    assert [a.text for a in fv.take_new_alerts()] == [
        "datagrams dropped (bad_tag): 1",
        "datagrams dropped (bad_tag): 10",
        "datagrams dropped (bad_tag): 100",
    ]


# -- image utility (thesis eq. 7.1 / 7.2) --------------------------------------------------
def image(type_: str, data: dict[str, object], *, quality: float = 1.0) -> Message:
    """An image message of ``type_`` carrying a version of ``quality``."""
    versions: tuple[Version, ...] = (Version(name="full", size=40, quality=1.0),)
    if quality != 1.0:
        versions += (Version(name="part", size=10, quality=quality),)
    return Message(sender="d", seq=1, type=type_, t_gen=T0, size=10, data=data,
                   versions=versions, version=len(versions) - 1)


def test_image_utility_equations() -> None:
    u = ImageUtility(alpha=10.0)
    assert u.weight(image("image", {"red": 0.25})) == pytest.approx(3.5)  # 1 + 10·0.25
    assert u.weight(image("image", {"object": True})) == 11.0  # 1 + α
    assert u.weight(image("image", {"object": False, "red": 0.0})) == 1.0
    assert u.weight(image("image", {"red": 0.5}, quality=0.25)) == pytest.approx(1.5)
    assert u.weight(image("image", {})) == 1.0


def test_image_utility_from_mission_spec() -> None:
    u = image_utility_from_spec(SPECS / "all_types.toml", alpha=1.0)
    assert u.by_type["image"].name == "red_image" and u.by_type["image"].params()["alpha"] == 10
    assert u.by_type["target"].name == "object_image"
    assert u.by_type["target"].params()["alpha"] == 10.0
    # an object flag on a red_image type does not count; red on object_image neither
    assert u.weight(image("image", {"red": 0.1, "object": True})) == pytest.approx(2.0)
    assert u.weight(image("target", {"red": 0.9})) == 1.0
    assert u.weight(image("other", {"red": 0.5})) == pytest.approx(1.5)  # config α = 1
    # plain video types of the spec: red and objects do not make them worth more
    assert u.weight(image("video", {"red": 0.3, "object": True}, quality=0.5)) == 0.5
    assert u.weight(image("thumbnail", {"red": 0.3})) == 1.0


# -- broadcaster ---------------------------------------------------------------------------
async def test_slow_client_drops_oldest_and_never_blocks() -> None:
    b = Broadcaster(queue_size=3)
    slow, fast = b.register(), b.register()
    for i in range(10):
        b.publish("n", {"i": i})
        if i % 2:
            while not fast.queue.empty():
                fast.queue.get_nowait()
    got = [slow.queue.get_nowait() for _ in range(slow.queue.qsize())]
    assert [int(g.split(":")[-1].strip(" }")) for g in got] == [7, 8, 9]
    assert slow.dropped == 7 and fast.dropped == 0
    b.unregister(slow)
    assert b.clients == {fast}
    await asyncio.sleep(0)


# -- config --------------------------------------------------------------------------------
def test_config_from_toml(tmp_path: Path) -> None:
    key = tmp_path / "fleet.key"
    key.write_text("0123456789abcdef-key\n")
    key.chmod(0o600)  # a secret others may read is refused (tests/security/test_key_files.py)
    path = tmp_path / "gs.toml"
    path.write_text(
        '[ground_station]\nfleet_id = 9\nfleet_key_file = "fleet.key"\ndata_dir = "data"\n'
        "udp_port = 14601\nalpha = 5\npublic_read = true\n"
    )
    config = load_config(path)
    assert config.fleet_id == 9 and config.fleet_key == b"0123456789abcdef-key"
    assert config.data_dir == tmp_path / "data" and config.alpha == 5.0
    assert config.public_read is True and config.token_path == tmp_path / "data" / "token"


@pytest.mark.parametrize(
    ("body", "key", "expected"),
    [
        ("udp_port = 'x'", "udp_port", "an integer port"),
        ("udp_port = 70000", "udp_port", "a port 0..65535"),
        ("alpha = true", "alpha", "a number"),
        ("fleet_key = 'short'", "fleet_key", "at least 16 bytes"),
        ("colour = 'red'", "colour", "one of"),
        ("udp_prot = 5", "udp_prot", "expected a known key (did you mean 'udp_port'?), one of"),
        ("report_interval_s = 0", "report_interval_s", "a number > 0"),
    ],
)
def test_config_errors_name_file_key_expected(
    tmp_path: Path, body: str, key: str, expected: str
) -> None:
    path = tmp_path / "bad.toml"
    path.write_text(body + "\n")
    with pytest.raises(ConfigError) as info:
        load_config(path)
    text = str(info.value)
    assert str(path) in text and repr(key) in text and expected in text


def test_config_missing_file_and_syntax(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="existing TOML file") as missing:
        load_config(tmp_path / "nope.toml")
    assert str(missing.value) == f"{tmp_path / 'nope.toml'}: expected an existing TOML file"
    (tmp_path / "x.toml").write_text("a = [")
    with pytest.raises(ConfigError, match="valid TOML"):
        load_config(tmp_path / "x.toml")
    assert GroundConfig().station_id == "gs"


def test_versions_quality_in_message() -> None:
    m = Message(
        sender="d",
        seq=1,
        type="image",
        t_gen=T0,
        size=10,
        versions=(
            Version(name="full", size=40, quality=1.0),
            Version(name="half", size=10, quality=0.5),
        ),
        version=1,
    )
    assert ImageUtility(alpha=10).weight(replace(m, data={"red": 1.0})) == 5.5


def write_spec(path: Path, utility: str, params: str) -> Path:
    path.write_text(f'[mission]\nname = "m"\n\n[types.image]\nutility = "{utility}"\n'
                    f'aggregation = "max"\nper_sender = true\nparams = {{ {params} }}\n')
    return path


@pytest.mark.parametrize(
    ("utility", "params", "expected"),
    [
        ("red_image", "alpha = 10.0", 0.5 * (1 + 10 * 0.2)),  # eq. 7.1 x quality
        ("red_image", "alpha = 2.0", 0.5 * (1 + 2 * 0.2)),  # the spec's α, not the config's 7
        ("object_image", "alpha = 4.0", 0.5 * (1 + 4.0)),  # eq. 7.2: the object flag counts
        ("video", "S = 0.1", 0.5),  # eq. 4.28: only the carried version's quality
        ("video_versions", "S = 0.1", 300 / 1200),  # eq. 4.33: diagonal / full diagonal
    ],
)
def test_image_weight_follows_the_specs_function(
    tmp_path: Path, utility: str, params: str, expected: float
) -> None:
    """One image, one type name, different spec functions: the weight is that function's
    scale (``Video.scale``), the same number the evaluator multiplies U_vid with."""
    u = image_utility_from_spec(write_spec(tmp_path / "s.toml", utility, params), alpha=7.0)
    m = image("image", {"red": 0.2, "object": True, "diagonal": 300.0, "full_diagonal": 1200.0},
              quality=0.5)
    assert u.weight(m) == pytest.approx(expected)
    assert u.weight(m) == pytest.approx(u.by_type["image"].scale(m))


@given(
    arrivals=st.lists(st.floats(min_value=0.0, max_value=5.0, allow_nan=False), max_size=40),
    repeat=st.integers(min_value=1, max_value=4),
)
def test_every_delivery_is_reported_exactly_repeat_times(
    arrivals: list[float], repeat: int
) -> None:
    """Property: with no overflow, each entry is in exactly ``repeat`` consecutive reports."""
    rs = ReportScheduler(interval_s=0.25, repeat=repeat, now=T0)
    seen: dict[int, list[int]] = {}
    events = sorted((T0 + t, i) for i, t in enumerate(arrivals))
    k = 0
    report_index = 0
    now = T0
    while k < len(events) or now < T0 + 5.0 + 0.25 * (repeat + 1):
        now = rs.get_timer()
        while k < len(events) and events[k][0] < now:
            t, i = events[k]
            rs.on_message(msg(i, t_gen=t, t_rcv=t), t_rcv=t)
            k += 1
        report = rs.due(now=now)
        assert report is not None
        for entry in report.entries:
            seen.setdefault(entry.seq, []).append(report_index)
        report_index += 1
    assert set(seen) == set(range(len(arrivals)))
    for indices in seen.values():
        assert indices == list(range(indices[0], indices[0] + repeat))
