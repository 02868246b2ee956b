"""The ground-station fixtures (a config in tmp_path, a live app client), shared here."""

from tests.ground_station.conftest import gs_client, gs_config

__all__ = ["gs_client", "gs_config"]
