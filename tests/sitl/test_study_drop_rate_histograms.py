"""``drop-rate-vs-utility``: its histograms come from the same random-drop runs as its curves."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

from sitl.study import drop_rate


def test_histogram_runs_are_the_curves_random_drop_runs(tmp_path: Path,
                                                         monkeypatch: pytest.MonkeyPatch) -> None:
    calls: list[tuple[str, str, float, int]] = []
    real = drop_rate.run_mission

    def recording(scenario: str, policy: str, param: float, *, seed: int,
                  **kw: Any) -> Any:
        calls.append((scenario, policy, param, seed))
        return real(scenario, policy, param, seed=seed, **kw)

    monkeypatch.setattr(drop_rate, "run_mission", recording)
    monkeypatch.setattr(drop_rate, "optimum_gap", lambda *a, **k: (100.0, 100.0, 0.0))
    assert drop_rate.main(["--out", str(tmp_path), "--quick", "--scenario", "uniform"]) == 0
    random_calls = [c for c in calls if c[1] == "random"]
    curves = random_calls[: len(random_calls) // 2]
    histograms = random_calls[len(random_calls) // 2:]
    assert curves and histograms == curves  # same drop shares, same seeds, same draws
