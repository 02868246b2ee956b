"""Two agents of the fig. 5.7 mostly-low fleet at a tight budget (two messages per window),
shared by the announcement and roster tests of the middleware."""

from __future__ import annotations

from companion.middleware import ConstantConstraint, Middleware, MiddlewareConfig
from utility_specs.files import builtin_spec
from utility_specs.message import Message

SPEC = builtin_spec("sim_mostly_low")  # agent i sends battery_i, weight 3^(i+1)
DATA = {"level": 1.0, "depletion_rate": 0.2}
WINDOW_S = 2.5


def battery(i: int, seq: int, t: float, **kw: float) -> Message:
    return Message(sender=f"agent{i}", seq=seq, type=f"battery_{i}", t_gen=t, size=2048,
                   data=DATA, **kw)


def agent(i: int, spec: object = SPEC, **kw: object) -> Middleware:
    """Two messages per window: a tight budget of the fig. 5.7 fleet."""
    config = MiddlewareConfig(spec=spec, agent=f"agent{i}", max_iterations=300,  # type: ignore[arg-type]
                              horizon_s=5.0, **kw)  # type: ignore[arg-type]
    return Middleware(config, constraint=ConstantConstraint(
        limit_bytes_per_s=2 * 2048 / WINDOW_S, window_s=WINDOW_S))


def mission_start(**kw: object) -> tuple[Middleware, Middleware, int, bool]:
    """agent0 (weight 3) generates at 0.5 and 1.5 s, agent9 (weight 59049) first at 1.6 s;
    agent9 hears agent0's sends 10 ms after them. Returns both agents, how many of its two
    messages agent0 sent and whether agent9's went out."""
    light, heavy = agent(0, **kw), agent(9, **kw)
    sent = 0
    for k, t in enumerate((0.5, 1.5)):
        if light.decide(battery(0, k, t), t).send:
            sent += 1
            heavy.on_delivered([battery(0, k, t, t_sent=t).delivered(
                receiver="ground", t_rcv=t + 0.01)], t + 0.01)
    return light, heavy, sent, heavy.decide(battery(9, 0, 1.6), 1.6).send
