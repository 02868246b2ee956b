"""``uav-sitl study fig7.3``: see :mod:`sitl.study.fig7`."""

from sitl.study.fig7 import main_73 as main

__all__ = ["main"]
