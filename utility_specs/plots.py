"""The figures of thesis ch. 4 for example missions (figures 4.2-4.10).

Message utilities are dashed, the aggregation is solid and filled, generation times are
arrows pointing up and receptions arrows pointing down, as in the thesis. Sampling on a grid
is fine here: it only draws; the numbers come from :func:`utility_specs.evaluate.evaluate`.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from utility_specs.evaluate import aggregate_at, evaluate
from utility_specs.functions import (
    Battery,
    Localization,
    Objective,
    Position,
    Status,
    StatusPoisson,
    UtilityFunction,
    Video,
)
from utility_specs.message import Message, StateHistory
from utility_specs.spec import InfoType, MissionSpec

__all__ = ["EXAMPLES", "Example", "plot", "utility_per_second"]


@dataclass(frozen=True, slots=True, kw_only=True)
class Example:
    """An example mission with one information type received by one agent."""

    figure: str
    title: str
    info: InfoType
    messages: tuple[Message, ...]
    t_end: float
    history: StateHistory = field(default_factory=StateHistory)


def _stream(
    type_name: str,
    pairs: Sequence[tuple[float, float]],
    data: Sequence[dict[str, Any]] | None = None,
) -> tuple[Message, ...]:
    data = data or [{} for _ in pairs]
    return tuple(
        Message(sender="a", receiver="g", seq=i, type=type_name, t_gen=g, t_rcv=r, data=d)
        for i, ((g, r), d) in enumerate(zip(pairs, data, strict=True))
    )


def _info(name: str, fn: UtilityFunction, aggregation: str) -> InfoType:
    return InfoType(name=name, utility=fn, aggregation=aggregation)  # type: ignore[arg-type]


def _localization_example() -> Example:
    # 1-D agent position over time; it observes cells [x-2, x+2]; three map fragments arrive.
    times = np.arange(0.0, 20.0, 0.25)
    position = 10 + 6 * np.sin(times / 3.0)
    records = [
        (float(t), {"observed_cells": [[c, 0] for c in range(int(x) - 2, int(x) + 3)]})
        for t, x in zip(times, position, strict=True)
    ]
    fragments = [range(9, 16), range(3, 9), range(12, 19)]
    messages = _stream(
        "map",
        [(2.0, 2.7), (6.0, 6.7), (12.0, 12.7)],
        [{"cells": [[c, 0] for c in cells]} for cells in fragments],
    )
    return Example(
        figure="4.8",
        title="A_loc and U_loc (eq. 4.20-4.22)",
        info=_info("map", Localization(), "sum"),
        messages=messages,
        t_end=20.0,
        history=StateHistory(records),
    )


EXAMPLES: dict[str, Callable[[], Example]] = {
    "battery": lambda: Example(
        figure="4.2",
        title="A_batt and U_batt (eq. 4.9/4.10), ρ = 0.05/s",
        info=_info("battery", Battery(depletion_rate=0.05), "max"),
        messages=_stream(
            "battery",
            [(1.0, 2.0), (5.0, 5.5), (9.0, 12.0), (14.0, 14.5)],
            [{"level": v} for v in (0.9, 0.7, 0.6, 0.3)],
        ),
        t_end=20.0,
    ),
    "position": lambda: Example(
        figure="4.3",
        title="A_pos and U_pos (eq. 4.12/4.13), v_max = 1 m/s, A = 200 m²",
        info=_info("position", Position(v_max=1.0, area=200.0), "max"),
        messages=_stream("position", [(1.0, 1.5), (4.0, 6.0), (10.0, 10.5), (13.0, 13.2)]),
        t_end=20.0,
    ),
    "status": lambda: Example(
        figure="4.4",
        title="A_status and U_status (eq. 4.14/4.15)",
        info=_info("status", Status(), "last"),
        messages=_stream("status", [(0.5, 1.0), (4.0, 6.0), (9.0, 9.5), (14.0, 17.0)]),
        t_end=20.0,
    ),
    "status_poisson": lambda: Example(
        figure="4.5",
        title="A_status' and U_status' (eq. 4.16/4.17), λ = 0.5",
        info=_info("status", StatusPoisson(rate=0.5), "max"),
        messages=_stream("status", [(1.0, 1.5), (5.0, 6.0), (9.0, 9.2), (14.0, 15.0)]),
        t_end=20.0,
    ),
    "objective": lambda: Example(
        figure="4.6",
        title="A_objective and U_objective (eq. 4.18/4.19)",
        info=_info("objective", Objective(), "sum"),
        messages=_stream(
            "objective",
            [(0.2, 0.6), (5.0, 5.5), (10.0, 11.0)],
            [{"objective": o} for o in ("o1", "o2", "o3")],
        ),
        t_end=20.0,
        history=StateHistory(
            [
                (0.0, {"objectives": []}),
                (1.0, {"objectives": ["o1"]}),
                (7.0, {"objectives": ["o1", "o2"]}),
                (9.0, {"objectives": ["o2"]}),
                (12.0, {"objectives": ["o2", "o3"]}),
            ]
        ),
    ),
    "localization": _localization_example,
    "video": lambda: Example(
        figure="4.10",
        title="A_vid and U_vid (eq. 4.28/4.29), S = 0.1, f_max = 24 Hz, f_1 = 12 Hz",
        info=_info("video", Video(S=0.1, f_max=24.0, f_1=12.0), "max"),
        messages=_stream("video", [(0.0, 0.02), (0.5, 0.55), (0.6, 0.65), (2.0, 2.1)]),
        t_end=5.0,
    ),
}
FIGURES = {
    **{example().figure: name for name, example in EXAMPLES.items()},
    "4.7": "localization-map",
    "4.9": "video-rate",
}


def utility_per_second(fn: Video, rate_hz: float, *, duration_s: float = 100.0) -> float:
    """Total utility per second of a stream at a constant frame rate without delays (fig. 4.9)."""
    n = round(duration_s * rate_hz)
    messages = [
        Message(sender="a", receiver="g", seq=i, type="video", t_gen=i / rate_hz, t_rcv=i / rate_hz)
        for i in range(n + 1)
    ]
    spec = MissionSpec(name="fig4.9", types={"video": _info("video", fn, "max")})
    return evaluate(messages, spec, t_end=n / rate_hz).total / (n / rate_hz)


def _draw_example(example: Example, ax: Any) -> None:
    grid = np.linspace(0.0, example.t_end, 2001)
    colors = ["tab:green", "tab:orange", "tab:purple", "tab:brown", "tab:pink", "tab:cyan"]
    fn = example.info.utility
    prepared = fn.prepare(list(example.messages)) or list(example.messages)
    for i, m in enumerate(prepared):
        assert m.t_rcv is not None
        shown = grid[grid >= m.t_rcv]
        values = [fn.value(m, float(t), example.history.at(float(t))) for t in shown]
        color = colors[i % len(colors)]
        ax.plot(shown, values, "--", color=color, lw=1.2)
        ax.annotate("", xy=(m.t_gen, 0.08), xytext=(m.t_gen, -0.12),
                    arrowprops={"arrowstyle": "->", "color": color})
        ax.annotate("", xy=(m.t_rcv, -0.12), xytext=(m.t_rcv, 0.08),
                    arrowprops={"arrowstyle": "->", "color": color, "ls": "dotted"})
    aggregate = [
        aggregate_at(example.info, example.messages, float(t), example.history.at(float(t)))
        for t in grid
    ]
    ax.plot(grid, aggregate, color="black", lw=1.6, label="aggregation")
    ax.fill_between(grid, aggregate, color="tab:blue", alpha=0.2)
    spec = MissionSpec(name=example.figure, types={example.info.name: example.info})
    total = evaluate(
        example.messages, spec, t_end=example.t_end, states={"g": example.history}
    ).total
    ax.set_title(f"Figure {example.figure}: {example.title}\ntotal utility {total:.3f}", fontsize=9)
    ax.set_xlabel("time [s]")
    ax.set_ylabel("utility")
    ax.set_xlim(0, example.t_end)
    ax.set_ylim(-0.15, max(1.1, max(aggregate) * 1.1))


def _draw_localization_map(ax: Any) -> None:
    example = _localization_example()
    colors = ["tab:green", "tab:orange", "tab:purple"]
    grid = np.linspace(0.0, example.t_end, 400)
    centres = []
    for t in grid:
        cells = example.history.at(float(t)).get("observed_cells", [])
        xs = [c[0] for c in cells]
        centres.append((min(xs), max(xs) + 1) if xs else (np.nan, np.nan))
    low, high = np.array(centres).T
    ax.fill_between(grid, low, high, color="0.85", label="observed area")
    ax.plot(grid, (low + high) / 2, "--", color="black", lw=1, label="agent position")
    for m, color in zip(example.messages, colors, strict=True):
        xs = [c[0] for c in m.data["cells"]]
        assert m.t_rcv is not None
        ax.add_patch(_rectangle(m.t_rcv, min(xs), example.t_end - m.t_rcv, max(xs) + 1 - min(xs),
                                color))
    ax.set_title("Figure 4.7: agent position and the received map data in 1-D", fontsize=9)
    ax.set_xlabel("time [s]")
    ax.set_ylabel("position (map cells)")
    ax.set_xlim(0, example.t_end)
    ax.legend(loc="upper right", fontsize=7)


def _rectangle(x: float, y: float, w: float, h: float, color: str) -> Any:
    from matplotlib.patches import Rectangle

    return Rectangle((x, y), w, h, color=color, alpha=0.35)


def _draw_video_rate(ax: Any) -> None:
    fn = Video(S=0.1, f_max=24.0, f_1=12.0)
    rates = [0.5, 0.75, 1, 1.5, 2, 3, 4, 6, 8, 12, 16, 24, 32, 48]
    achieved = [utility_per_second(fn, r) for r in rates]
    reference = utility_per_second(fn, fn.f_1)
    dense = np.geomspace(rates[0], fn.f_max, 200)
    ideal = reference + fn.S * np.log2(dense / fn.f_1)
    ax.semilogx(dense, ideal, color="tab:blue", label="ideal: S·log2(f/f0)")
    ax.semilogx(rates, achieved, "o", color="tab:red", mfc="none", label="eq. 4.28 over 100 s")
    ax.set_title("Figure 4.9: total utility per second vs frame rate\n"
                 "S = 0.1, f_max = 24 Hz, f_1 = 12 Hz", fontsize=9)
    ax.set_xlabel("frame rate [Hz]")
    ax.set_ylabel("utility per second")
    ax.legend(fontsize=7)
    ax.grid(True, which="both", alpha=0.3)


KINDS = [*EXAMPLES, "localization-map", "video-rate"]


def plot(kind: str, out: str | Path) -> Path:
    """Draw one figure (a name from :data:`KINDS` or a thesis figure number) to a PNG."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    kind = FIGURES.get(kind.removeprefix("fig").removeprefix("ure").strip(), kind)
    if kind not in KINDS:
        raise ValueError(f"unknown plot {kind!r}; expected one of {', '.join(KINDS)} or 4.2-4.10")
    fig, ax = plt.subplots(figsize=(7, 3.6), dpi=120)
    if kind == "localization-map":
        _draw_localization_map(ax)
    elif kind == "video-rate":
        _draw_video_rate(ax)
    else:
        _draw_example(EXAMPLES[kind](), ax)
    fig.tight_layout()
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out)
    plt.close(fig)
    return out
