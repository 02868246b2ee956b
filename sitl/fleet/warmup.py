"""Wait for every companion's optimiser to warm up before the mission starts.

On a cold numba cache the optimiser compiles for up to half a minute (four companions at once
on two cores: more); until then a companion sends only its status heartbeat, so a mission
started as soon as the drones are heard would show no images for that long. Each status says
``optimiser_ready`` and the station's ``/api/fleet`` shows it per drone; the launcher waits
for all of them, printing progress, and starts anyway (with a warning) after a timeout.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping, Sequence
from typing import IO, Any

from sitl.fleet.processes import Child, FleetError, Stop, Stopped

PROGRESS_EVERY_S = 10.0
"""Without a change, the progress line is repeated this often (so a slow compile shows)."""


def warm_drones(fleet: Mapping[str, Any] | None) -> set[str]:
    """The drones whose optimiser the station last heard ready (``/api/fleet``)."""
    drones = (fleet or {}).get("drones") or []
    return {str(d.get("drone")) for d in drones
            if isinstance(d, Mapping) and d.get("optimiser_ready") is True}


def wait_for_warm_up(fleet: Callable[[], Mapping[str, Any] | None], drone_ids: Sequence[str],
                     *, stop: Stop, timeout_s: float, out: IO[str],
                     watch: Sequence[Child] = (), poll_s: float = 0.2,
                     clock: Callable[[], float] = time.monotonic) -> list[str]:
    """Poll ``fleet`` (the station's ``/api/fleet``, None when unreachable) until every one
    of ``drone_ids`` reports its optimiser ready; print progress to ``out``.

    Returns the drones still warming up when ``timeout_s`` ran out (empty: all warm). Raises
    :class:`FleetError` when a watched process exits or a stop is asked for.
    """
    wanted = list(drone_ids)
    n = len(wanted)
    t0 = clock()
    shown: tuple[int, float] | None = None
    while True:
        warm = warm_drones(fleet()) & set(wanted)
        elapsed = clock() - t0
        if len(warm) == n:
            if shown is not None:  # said we were waiting: say it is over
                print(f"companions warm: {n}/{n} after {elapsed:.1f} s", file=out)
            else:
                print(f"companions warm: {n}/{n} (optimiser ready)", file=out)
            out.flush()
            return []
        if shown is None or len(warm) != shown[0] or elapsed - shown[1] >= PROGRESS_EVERY_S:
            print(f"waiting for {n} companions to warm up (optimiser compiling) "
                  f"{len(warm)}/{n}... {elapsed:.0f} s", file=out)
            out.flush()
            shown = (len(warm), elapsed)
        for child in watch:
            if not child.alive():
                raise FleetError(f"{child.name} exited ({child.proc.returncode}) while "
                                 f"waiting for the companions to warm up; its log "
                                 f"({child.log_path}) ends with:\n{child.tail()}")
        if elapsed > timeout_s:
            return [d for d in wanted if d not in warm]
        if stop.sleep(poll_s):
            raise Stopped(f"stopped ({stop.reason}) while waiting for the companions to "
                             "warm up")
