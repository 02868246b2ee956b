"""Fixtures for the companion tests: a loopback MAVLink vehicle and small images."""

from __future__ import annotations

import os

os.environ.setdefault("MAVLINK20", "1")

from collections.abc import Iterator

import pytest
from companion_fake_vehicle import FakeVehicle


@pytest.fixture
def vehicle() -> Iterator[FakeVehicle]:
    v = FakeVehicle(autopilot="ardupilot").start()
    yield v
    v.stop()


@pytest.fixture
def px4_vehicle() -> Iterator[FakeVehicle]:
    v = FakeVehicle(autopilot="px4").start()
    yield v
    v.stop()
