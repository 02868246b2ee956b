"""Project-wide test settings."""

from __future__ import annotations

import os

# pymavlink picks its wire version from the environment at import time (STYLE.md): decide once.
os.environ.setdefault("MAVLINK20", "1")
