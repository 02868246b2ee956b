"""``python -m sitl.linkemu probe-sender|probe-receiver``."""

from sitl.linkemu.probe import main

raise SystemExit(main())
