"""The AIMD baseline constraint (thesis ch. 6.3, algorithm 4).

Per reported message:

1. if ‖W‖_Δ > α: ξ ← ξ · b
2. else if ξ − ‖W‖_G < β: ξ ← ξ + a
3. else ξ unchanged.

Units are kept consistent (the thesis' reference code added bytes to a bit rate): ξ, ‖W‖_G,
‖W‖_Δ, α and β are bytes per second and ``a`` is the bytes per second added per update.
Defaults are the thesis' a = 2048 B/s, b = 0.998, β = 0.05 Mbit/s = 6250 B/s.
"""

from __future__ import annotations

from companion.middleware.constraints.adaptive import LinkStatsConstraint
from companion.middleware.constraints.linkstats import LinkStats, WindowStats
from companion.middleware.errors import ConstraintError

__all__ = ["AimdConstraint"]


class AimdConstraint(LinkStatsConstraint):
    """Additive-increase / multiplicative-decrease ξ (algorithm 4), clamped to [min, max]."""

    def __init__(
        self,
        *,
        alpha_bytes_per_s: float = 12_500.0,
        increase_bytes_per_s: float = 2048.0,
        decrease_factor: float = 0.998,
        beta_bytes_per_s: float = 6250.0,
        initial_bytes_per_s: float = 62_500.0,
        min_bytes_per_s: float = 1_250.0,
        max_bytes_per_s: float = 12_500_000.0,
        window_s: float = 2.5,
        base_window_s: float = 10.0,
        min_base_latency_s: float = 0.005,
        fleet_goodput: bool = False,
        link_rate_bytes_per_s: float = 0.0,
        loss_is_congestion: bool = False,
        stats: LinkStats | None = None,
    ) -> None:
        super().__init__(
            window_s=window_s,
            stats=stats,
            base_window_s=base_window_s,
            min_base_latency_s=min_base_latency_s,
            fleet_goodput=fleet_goodput,
            link_rate_bytes_per_s=link_rate_bytes_per_s,
            loss_is_congestion=loss_is_congestion,
        )
        if not alpha_bytes_per_s > 0:
            raise ConstraintError(f"alpha_bytes_per_s must be > 0, got {alpha_bytes_per_s}")
        if not increase_bytes_per_s > 0:
            raise ConstraintError(f"increase_bytes_per_s must be > 0, got {increase_bytes_per_s}")
        if not 0 < decrease_factor < 1:
            raise ConstraintError(f"decrease_factor must be in (0, 1), got {decrease_factor}")
        if not beta_bytes_per_s >= 0:
            raise ConstraintError(f"beta_bytes_per_s must be >= 0, got {beta_bytes_per_s}")
        if not 0 < min_bytes_per_s <= max_bytes_per_s:
            raise ConstraintError(
                f"need 0 < min_bytes_per_s ({min_bytes_per_s}) <= max_bytes_per_s "
                f"({max_bytes_per_s})"
            )
        self.alpha_bytes_per_s = float(alpha_bytes_per_s)
        self.increase_bytes_per_s = float(increase_bytes_per_s)
        self.decrease_factor = float(decrease_factor)
        self.beta_bytes_per_s = float(beta_bytes_per_s)
        self.min_bytes_per_s = float(min_bytes_per_s)
        self.max_bytes_per_s = float(max_bytes_per_s)
        self._xi = min(max_bytes_per_s, max(min_bytes_per_s, float(initial_bytes_per_s)))

    def limit_bytes_per_s(self, *, now: float) -> float:
        del now
        return self._xi

    def _learn(self, observations: list[WindowStats]) -> None:
        for o in observations:
            if o.backlog_bytes_per_s > self.alpha_bytes_per_s:
                xi = self._xi * self.decrease_factor
            elif self._xi - o.goodput_bytes_per_s < self.beta_bytes_per_s:
                xi = self._xi + self.increase_bytes_per_s
            else:
                continue
            self._xi = min(self.max_bytes_per_s, max(self.min_bytes_per_s, xi))
