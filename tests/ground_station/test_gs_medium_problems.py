"""The station's ``shared_medium`` problems are one line naming the setting (docs/peers.md).

Seen by hand with ``uav-ground-station run``: a medium on the station's own ``udp_port``
printed "dashboard 127.0.0.1:28080 is already in use (another program listens there)" (the
dashboard was free), and a multicast interface that is not the station's printed "cannot
serve: [Errno 19] No such device".
"""

from __future__ import annotations

import pytest

from ground_station.cli import _serve_problem
from ground_station.config import ConfigError, GroundConfig
from ground_station.transport import UdpTransport
from tests.keys import TEST_COMMAND_KEY, TEST_FLEET_KEY


def test_a_medium_on_the_udp_port_is_a_configuration_error() -> None:
    with pytest.raises(ConfigError, match=r"key 'shared_medium': 'broadcast:127.255.255.255:"
                       r"14600' uses port 14600, the station's udp_port too"):
        GroundConfig(fleet_key=TEST_FLEET_KEY, command_key=TEST_COMMAND_KEY, udp_port=14600,
                     shared_medium="broadcast:127.255.255.255:14600")
    ok = GroundConfig(fleet_key=TEST_FLEET_KEY, command_key=TEST_COMMAND_KEY, udp_port=14600,
                      shared_medium="broadcast:127.255.255.255:14700")
    with pytest.raises(ConfigError, match="shared_medium"):  # --udp-port onto the medium
        ok.with_overrides(udp_port=14700)


async def test_a_medium_that_cannot_open_names_the_setting() -> None:
    config = GroundConfig(fleet_key=TEST_FLEET_KEY, command_key=TEST_COMMAND_KEY,
                          udp_host="127.0.0.1", udp_port=0,
                          shared_medium="multicast:239.255.42.99:14799:192.0.2.1")
    transport = UdpTransport("127.0.0.1", 0, rcvbuf_bytes=65536, medium=config.shared_medium)
    with pytest.raises(OSError) as info:
        await transport.open(lambda *args: None)  # type: ignore[arg-type]
    line = _serve_problem(info.value, config)
    assert line.startswith("shared_medium multicast:239.255.42.99:14799:192.0.2.1: cannot "
                           "open the shared medium ("), line
    assert "192.0.2.1 is not an address of this computer" in line
    assert transport._sock is None  # the station's own socket is closed again
