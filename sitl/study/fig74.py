"""``uav-sitl study fig7.4``: see :mod:`sitl.study.fig7`."""

from sitl.study.fig7 import main_74 as main

__all__ = ["main"]
