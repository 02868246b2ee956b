"""Every typed ``web.AppKey`` of the ground-station application (aiohttp "no singletons")."""

from __future__ import annotations

from collections.abc import Callable

from aiohttp import web

from ground_station.broadcast import Broadcaster
from ground_station.config import GroundConfig
from ground_station.fleet import FleetView
from ground_station.missions import MissionManager
from ground_station.receiver import GroundLink
from ground_station.store_service import StorageService
from ground_station.utility import ImageUtility

__all__ = [
    "BROADCASTER",
    "CLOCK",
    "CONFIG",
    "FLEET",
    "IMAGE_UTILITY",
    "LATEST_JPEG",
    "LINK",
    "MISSIONS",
    "STORAGE",
    "TOKEN",
    "WEBSOCKETS",
]

CONFIG = web.AppKey("config", GroundConfig)
CLOCK: web.AppKey[Callable[[], float]] = web.AppKey("clock")
"""Fleet clock (Unix seconds); ``time.time`` in production, injectable in tests."""
TOKEN = web.AppKey("token", str)
FLEET = web.AppKey("fleet", FleetView)
MISSIONS = web.AppKey("missions", MissionManager)
BROADCASTER = web.AppKey("broadcaster", Broadcaster)
IMAGE_UTILITY = web.AppKey("image_utility", ImageUtility)
STORAGE = web.AppKey("storage", StorageService)
LINK = web.AppKey("link", GroundLink)
LATEST_JPEG = web.AppKey("latest_jpeg", dict[str, bytes])
"""Newest image bytes per drone, served to tiles without touching the disk."""
WEBSOCKETS = web.AppKey("websockets", dict[web.WebSocketResponse, web.Request])
"""Open live feeds and their requests (a feed that does not read is aborted through it)."""
