"""The config refuses what ``run`` would fail on later: the same rules for check and run."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from companion.config import ConfigError, parse_config

SCHEMES = st.sampled_from(["udpin", "udpout", "udp", "tcp", "tcpin", "udpbcast"])
HOSTS = st.sampled_from(["0.0.0.0", "127.0.0.1", "192.168.1.10", "localhost"])


def _config(url: str, drone: str = "d1") -> dict[str, object]:
    return {"drone": {"id": drone}, "mavlink": {"url": url}}


@given(SCHEMES, HOSTS, st.integers(1, 65535))
def test_network_urls_with_a_real_port_pass(scheme: str, host: str, port: int) -> None:
    url = f"{scheme}:{host}:{port}"
    assert parse_config(_config(url)).mavlink.url == url


@given(SCHEMES, HOSTS, st.one_of(st.integers(65536, 10**9), st.just(0)))
def test_network_urls_with_an_impossible_port_fail(scheme: str, host: str, port: int) -> None:
    with pytest.raises(ConfigError, match=r"mavlink\.url: expected a pymavlink URL"):
        parse_config(_config(f"{scheme}:{host}:{port}"))


@pytest.mark.parametrize("url", ["/dev/serial0", "/dev/ttyACM0,921600", "/tmp/ttyFC", "COM3"])
def test_serial_paths_pass(url: str) -> None:
    assert parse_config(_config(url)).mavlink.url == url


@pytest.mark.parametrize("url", ["udpin:14550", "udpin:0.0.0.0:", "serial0", "tcp:host:x",
                                 "/dev/serial0,fast", "udpin:0.0.0.0:14550\n"])
def test_malformed_urls_fail(url: str) -> None:
    with pytest.raises(ConfigError, match=r"mavlink\.url"):
        parse_config(_config(url))


@given(st.text(min_size=1, max_size=40).filter(str.isprintable))
def test_drone_ids_follow_the_wire_limit(drone: str) -> None:
    fits = len(drone.encode("utf-8", "surrogatepass")) <= 32
    if fits:
        assert parse_config(_config("udpin:0.0.0.0:14550", drone)).drone_id == drone
    else:
        with pytest.raises(ConfigError, match=r"drone\.id: expected a printable sender id"):
            parse_config(_config("udpin:0.0.0.0:14550", drone))
