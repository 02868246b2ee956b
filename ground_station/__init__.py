"""The ground station: UDP receiver, receiver reports, storage, dashboard, mission manager.

``create_app(config)`` builds the aiohttp application (``uav-ground-station run`` serves
it); see docs/ground_station.md.
"""

from ground_station.app import create_app
from ground_station.config import ConfigError, GroundConfig, load_config

__all__ = ["ConfigError", "GroundConfig", "create_app", "load_config"]
