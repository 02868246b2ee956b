"""``uav-sitl study fig4.13``: thesis ch. 4.5, battery reports over a lossy direct link or a
delayed Internet link, evaluated by the model (figures 4.11-4.13)."""

from __future__ import annotations

import csv
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from sitl.study import fig413

SITL = Path(sys.executable).parent / "uav-sitl"


def test_a_perfect_link_is_worth_what_the_battery_model_says() -> None:
    """Two agents, one report a second: each stream is worth ∫ 1 − ρ·age/level over the
    mission, age a sawtooth 0..1 s from the first report on (exact from eq. 4.9)."""
    phases = np.random.default_rng([3, 0]).uniform(0.0, 1.0, 2)
    expected = 0.0
    for phase in phases:
        t_gen = np.arange(phase, fig413.T_END_S, 1.0)
        level = 1.0 - 0.12 * t_gen / fig413.T_END_S
        gap = np.diff(np.append(t_gen, fig413.T_END_S))  # the last one until the end
        # each report holds until the next: ∫_0^gap 1 - ρ x / level dx
        expected += float(np.sum(gap - fig413.DEPLETION_PER_S * gap**2 / (2 * level)))
    assert fig413.mission_utility(agents=2, delay_s=0.0, loss=0.0, seed=3) == pytest.approx(
        expected, rel=1e-9)


def test_delay_and_loss_cost_what_the_closed_form_says() -> None:
    """The same runs (common random numbers) at 0 and at 0.5 s, and at loss 0 and 0.2: a
    delay d costs each stream d of its start and d of age all mission; a loss p costs
    p / (1 - p) of both, so the simulated break-even delay is the closed form's."""
    runs = range(150)

    def mean(delay: float, loss: float) -> float:
        return float(np.mean([fig413.mission_utility(agents=3, delay_s=delay, loss=loss,
                                                     seed=r) for r in runs]))

    base, late = mean(0.01, 0.0), mean(0.51, 0.0)
    per_s = (base - late) / 0.5  # utility per second of delay
    lossy = mean(0.01, 0.2)
    simulated = 0.01 + (base - lossy) / per_s
    assert simulated == pytest.approx(fig413.break_even_delay_s(0.2), abs=0.02)
    assert fig413.break_even_delay_s(0.2) == pytest.approx(0.01 + 0.25)
    # more loss is never worth more on common random numbers (a lost copy stays lost)
    assert mean(0.01, 0.1) > lossy > mean(0.01, 0.3)


def test_quick_study_writes_the_three_figures_and_the_table(tmp_path: Path) -> None:
    run = subprocess.run([str(SITL), "study", "fig4.11", "--quick", "--out", str(tmp_path)],
                         capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stderr[-2000:]
    rows = list(csv.DictReader((tmp_path / "fig4_11_13.csv").open()))
    links = {r["link"] for r in rows}
    assert links == {"internet", "direct"}
    assert len(rows) == 5 * (11 + 7)  # 5 runs at 11 delays and 7 loss rates
    for name in ("fig4_11", "fig4_12", "fig4_13"):
        assert (tmp_path / f"{name}.png").stat().st_size > 15_000
    assert "internet link, 11 points x 5 run(s) done" in run.stdout
    table = run.stdout.split("(closed form)")[1].splitlines()
    at_01 = next(line for line in table if line.strip().startswith("0.10 |"))
    closed = float(at_01.split("|")[3].split()[0])
    assert closed == pytest.approx(0.01 + 0.1 / 0.9, abs=1e-3)
    net = [float(r["utility"]) for r in rows if r["link"] == "internet"
           and float(r["delay_s"]) in (0.0, 1.0)]
    assert not any(math.isnan(u) for u in net)


@pytest.mark.parametrize("bad", [["--agents", "1"], ["--runs", "0"], ["--jitter", "2"]])
def test_bad_options_are_a_one_line_usage_error(tmp_path: Path, bad: list[str]) -> None:
    run = subprocess.run([str(SITL), "study", "fig4.13", "--out", str(tmp_path), *bad],
                         capture_output=True, text=True, timeout=60)
    assert run.returncode == 2 and "Traceback" not in run.stderr
    assert "--agents must be in 2..50" in run.stderr.splitlines()[-1]
