"""``python -m sitl.fleet ...``: the same as ``uav-sitl fleet ...``."""

import sys

from sitl.fleet.cli import main

raise SystemExit(main(sys.argv[1:]))
