"""The companion against the project's SITL vehicle (``uav-sitl vehicle``) with the synthetic
camera: the whole drone side as processes, the way ``uav-sitl fleet`` runs it."""

from __future__ import annotations

import json
import socket
import subprocess
import sys
from pathlib import Path

import pytest
from test_companion_system import (  # type: ignore[import-not-found]
    Receiver,
    _write_config,
    receiver,  # noqa: F401 - fixture
)

from tests.companion_process import start_companion, stop_companion, until

SITL = Path(sys.executable).parent / "uav-sitl"


def _free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


@pytest.mark.timeout(120)
@pytest.mark.parametrize(("flavour", "link"), [("ardupilot", "udpout"), ("px4", "udpin")])
async def test_companion_with_sitl_vehicle_and_synthetic_camera(
        receiver: tuple[Receiver, int], tmp_path: Path, flavour: str,  # noqa: F811
        link: str) -> None:
    """udpout: we send first and the vehicle answers; udpin: the vehicle sends to our port
    (how a flight controller's telemetry port or ``--out`` of a SITL is usually set up)."""
    pytest.importorskip("sitl.camera")
    if not SITL.exists():
        pytest.skip("uav-sitl is not installed in this environment")
    rx, gs_port = receiver
    companion_port = _free_udp_port()
    out = ["--out", f"127.0.0.1:{companion_port}"] if link == "udpin" else []
    vehicle = subprocess.Popen([str(SITL), "vehicle", "--port", "0", "--flavour", flavour,
                                "--pattern", "orbit", "--autostart", "--first-fix", "0", *out],
                               stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    try:
        assert vehicle.stdout is not None
        ready = json.loads(vehicle.stdout.readline().removeprefix("READY "))
        config = _write_config(
            tmp_path / "d1.toml", drone="d1", vehicle_port=ready["port"], gs_port=gs_port,
            mavlink_url=f"udpin:127.0.0.1:{companion_port}" if link == "udpin" else None,
            frames=Path("synthetic"), rate_hz=2.0,
            constraint='[constraint]\nname = "constant"\n'
                       'params = { limit_bytes_per_s = 100000.0 }',
            extra='[camera.options]\nscene = "demo"\n')
        proc = start_companion(config, json_logs=True)
        try:
            await until(lambda: rx.of("d1", "image") and rx.of("d1", "position"), 60, proc)
            status = rx.of("d1", "status")[-1]
            assert status.data["autopilot"] == flavour
            position = rx.of("d1", "position")[-1]
            home_lat, home_lon = ready["home"][:2]
            assert abs(position.data["lat_deg"] - home_lat) < 0.01
            assert abs(position.data["lon_deg"] - home_lon) < 0.01
            image = rx.of("d1", "image")[-1]
            assert "lat_deg" in image.data and 0.0 <= image.data["red"] <= 1.0
        finally:
            code, err = stop_companion(proc)
        assert code == 0, err[-3000:]
    finally:
        vehicle.terminate()
        try:
            vehicle.wait(10)
        except subprocess.TimeoutExpired:
            vehicle.kill()
