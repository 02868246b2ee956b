"""The adaptive goodput constraint ξ(t) = R_t(α) (thesis ch. 6.2, eq. 6.6-6.8).

A linear data-rate model R(‖W‖_Δ) ≈ ‖W‖_G is fitted online, one stochastic-gradient step
(squared loss) per reported message, with scikit-learn's ``SGDRegressor.partial_fit``.
The constraint is the model's goodput at the tolerated backlog α, clamped to sane bounds.
Because every reported message is a training sample, the model keeps learning while the
application sends far less than ξ: more background traffic raises ‖W‖_Δ at the same
goodput, the fit moves and ξ falls (figure 6.5, 65-75 s).

Rates are fitted in units of ``scale_bytes_per_s``; set it to the link's order of magnitude
and a learning rate tuned on a 1 Mbit/s radio carries over to a 100 Mbit/s WiFi (the thesis
had to retune it per setup, ch. 7.3).
Pure compute: no clock, no I/O (SGDRegressor is a numeric routine).
"""

from __future__ import annotations

import dataclasses
import math
from abc import abstractmethod
from collections.abc import Iterable, Mapping
from typing import TYPE_CHECKING

import numpy as np

from companion.middleware.constraints.base import GoodputConstraint
from companion.middleware.constraints.linkstats import LinkSample, LinkStats, RoundTrip, WindowStats
from companion.middleware.constraints.losses import SendLedger
from companion.middleware.errors import ConstraintError

if TYPE_CHECKING:
    from sklearn.linear_model import SGDRegressor

__all__ = ["AdaptiveConstraint", "LinkStatsConstraint"]

KNEE_HOLD_WINDOWS = 1.5
"""How long (in windows T) a congestion episode may last before ξ may fall below the knee
band: a window over a queue that formed at the knee shows congestion for up to one T."""

KNEE_FORGET_WINDOWS = 2.0
"""After this many windows T without congestion the knee no longer slows ξ down."""



class LinkStatsConstraint(GoodputConstraint):
    """A constraint that learns from link statistics of receiver reports (ch. 6).

    Feeds every sample to its :class:`LinkStats` and hands each warm window to
    :meth:`_learn`. Subclasses decide what ξ does with the observations.

    With ``loss_is_congestion`` it also keeps a :class:`SendLedger` of this agent's sends
    (:meth:`on_sent`); the windows learned from a report that shows a lost message read as
    a full queue (``backlog_bytes_per_s`` = inf, ``lost`` > 0), whatever their latency.
    """

    def __init__(
        self,
        *,
        window_s: float,
        stats: LinkStats | None = None,
        base_window_s: float = 10.0,
        min_base_latency_s: float = 0.005,
        fleet_goodput: bool = False,
        link_rate_bytes_per_s: float = 0.0,
        loss_is_congestion: bool = False,
    ) -> None:
        super().__init__(window_s=window_s)
        self.stats = stats if stats is not None else LinkStats(
            window_s=window_s, base_window_s=base_window_s, min_base_latency_s=min_base_latency_s,
            fleet_goodput=fleet_goodput, link_rate_bytes_per_s=link_rate_bytes_per_s,
        )
        self.n_updates = 0
        self.last_stats: WindowStats | None = None
        self.ledger: SendLedger | None = SendLedger() if loss_is_congestion else None
        """This agent's sends, to find the lost ones (``loss_is_congestion``); else None."""

    @property
    def loss_is_congestion(self) -> bool:
        """Whether a lost message makes the windows of its report congested."""
        return self.ledger is not None

    def on_sent(self, size_bytes: int, *, now: float) -> None:
        super().on_sent(size_bytes, now=now)
        if self.ledger is not None:
            self.ledger.on_sent(size_bytes, now=now)

    @property
    def fleet_goodput(self) -> bool:
        """Whether other agents' report entries count in the goodput (LinkStats)."""
        return self.stats.fleet_goodput

    def on_sample(self, sample: LinkSample, *, now: float) -> None:
        """One update per delivered message (thesis: 'whenever a new message is received')."""
        self.on_samples([sample], now=now)

    def on_samples(self, samples: Iterable[LinkSample], *, now: float) -> None:
        """All messages of one report: still one model update per message of this agent's
        (another agent's, with ``fleet_goodput``, only counts in the goodput)."""
        observations: list[WindowStats] = []
        lost = 0
        counters = self.stats.counters
        for sample in samples:
            before, stale = counters["samples"], counters["stale"]
            stats = self.stats.update(sample, now=now).get()
            if self.ledger is not None and sample.own and (
                    counters["samples"] > before or counters["stale"] > stale):
                lost += self.ledger.on_delivered(sample.size)  # arrived, even if late
            if counters["samples"] == before or stats is None:
                continue  # duplicate, stale, invalid or another agent's: nothing to learn
            if lost:  # a message sent before this one never arrived: the queue overflowed
                stats = dataclasses.replace(stats, backlog_bytes_per_s=math.inf, lost=lost)
            self.last_stats = stats
            if stats.warm:
                observations.append(stats)
        if observations:
            self._learn(observations)
            self.n_updates += len(observations)

    def on_round_trip(self, round_trip: RoundTrip, *, now: float) -> None:
        """A report round trip: refines the clock offset used for latencies."""
        del now
        self.stats.on_round_trip(round_trip)

    def on_stall(self, t_from: float, t_to: float, *, now: float) -> None:
        """Messages this agent sent while it stalled are neither latency nor loss samples."""
        del now
        self.stats.mark_stall(t_from, t_to)
        if self.ledger is not None:
            self.ledger.forget(t_from, t_to)

    @abstractmethod
    def _learn(self, observations: list[WindowStats]) -> None:
        """Update ξ from warm windows, one per newly reported message, in order."""


class AdaptiveConstraint(LinkStatsConstraint):
    """ξ(t) = clamp(R_t(α)) with R fitted by SGD on (‖W‖_Δ, ‖W‖_G) (eq. 6.7/6.8).

    Two safeguards on top of the thesis' plain SGD, both found necessary on a real queue:

    - *Projection onto increasing models* (``min_coef``). An application that keeps to ξ
      delivers G ≈ ξ, so the intercept alone can explain every sample and the fitted slope
      drifts to ~0; ξ = R(α) then stops reacting to Δ (a neutral equilibrium wherever it
      happens to be). The true R is increasing in Δ, so after each step the slope is
      projected back to ≥ ``min_coef``; that keeps a restoring force ∝ (α − Δ).
    - *Clipped backlog* (``backlog_clip``). In a congested queue Δ reaches tens of times the
      goodput; a squared-loss step grows with x², so one such sample makes plain SGD
      diverge. The linear model is meant for the uncongested regime (ch. 6.2), where
      clipping changes nothing; beyond ``backlog_clip · α`` a sample only says "congested".

    Parameters
    ----------
    alpha_bytes_per_s
        α, the tolerated backlog ‖W‖_Δ (eq. 6.6). Lower: lower latency and loss.
    learning_rate
        SGD step size (constant schedule) in scaled units; higher adapts faster, noisier.
    initial_coef
        Initial belief on dR/dΔ (dimensionless: goodput bytes per backlog byte).
    initial_intercept_bytes_per_s
        Initial belief on R(0). ξ starts at intercept + coef·α.
    min_bytes_per_s, max_bytes_per_s
        Bounds on ξ, so a wild fit can neither silence the application nor flood the link.
    scale_bytes_per_s
        Unit the model is fitted in (default 1 Mbit/s = 125000 B/s).
    min_coef
        Least slope dR/dΔ kept after each step (projected SGD onto increasing models).
    backlog_clip
        Observed Δ is clipped at ``backlog_clip · α`` before fitting.
    use_weighted
        Off (thesis-exact): every observation is one equal SGD step. On: a step is weighted
        by how much of ξ the application used in that window, min(1, ‖W‖_G/ξ), and a window
        over α (congestion) always counts fully. A window in which the application sent
        little says little about what the link carries; with equal steps an on/off demand
        drags ξ down and up with it (fig. 6.5: CV of ξ 0.14 against AIMD's 0.08, seed 1;
        weighted 0.055). It still learns at low use, only more slowly (docs/studies.md).
    knee_band, knee_step
        The knee memory (``knee_band`` 0: off, the thesis' SGD; ``make_constraint(
        "adaptive-smooth")`` turns it on with 0.05 / 0.01 and use-weighted steps). On a link
        with a sharp capacity (a token bucket, a radio's MCS rate) there is no gentle slope
        to fit: below the knee Δ ≈ 0, above it the queue grows, and plain SGD limit-cycles
        ±15 % around the knee in ~1.3 s (docs/adaptive.md). The knee is the goodput the link
        delivered in the last congestion episode (consecutive windows with Δ > α).
        Uncongested steps are weighted by ``knee_step`` at the knee, growing quadratically
        to full at ``knee_band`` · knee away from it (or after ``KNEE_FORGET_WINDOWS`` calm
        windows), so ξ approaches the knee slowly but recovers and probes a grown link at
        full speed; a new congestion episode lowers ξ to (1 − ``knee_band``) · knee and no
        further for ``KNEE_HOLD_WINDOWS`` (a queue formed at the knee shows in one window),
        after which congestion that persists (more background, a slower link) gets the full
        SGD.
    queueing_budget_s
        0 (thesis-exact): α is a fixed backlog. Above 0: α is raised, per window, to the
        backlog this much queueing delay makes at the window's goodput, G·q/δ̂ (eq. 6.4), so
        the tolerated queueing never shrinks below it as the link gets faster. A fixed α
        tolerates q = α·δ̂/G: 5 ms at 1 Mbit/s with the real-link α, but 2 ms at 2.5 Mbit/s,
        inside the 2-10 ms latency noise of a loaded host, where every noisy window read as
        congestion (docs/adaptive.md). Below the rate where G·q/δ̂ = α nothing changes.
    window_s
        T of both the link statistics and the budget window (eq. 6.1).
    fleet_goodput, link_rate_bytes_per_s
        What the link statistics are read with (:class:`LinkStats`; both off: the thesis'):
        the fleet's goodput instead of this agent's, and the link's rate, so a message's
        own transmission time does not read as queueing. The demo's narrow link needs both
        (``sitl.fleet.link.relay_constraint_params``, docs/adaptive.md).
    loss_is_congestion
        Off (the thesis'): only latency says congestion. On: a report that shows one of
        this agent's messages lost makes its windows congested (:class:`LinkStatsConstraint`).
    stats
        Link statistics to use (default: a new :class:`LinkStats` with ``window_s``).
    """

    def __init__(
        self,
        *,
        alpha_bytes_per_s: float = 12_500.0,
        learning_rate: float = 0.01,
        initial_coef: float = 1.0,
        initial_intercept_bytes_per_s: float = 62_500.0,
        min_bytes_per_s: float = 1_250.0,
        max_bytes_per_s: float = 12_500_000.0,
        scale_bytes_per_s: float = 125_000.0,
        min_coef: float = 0.1,
        backlog_clip: float = 4.0,
        use_weighted: bool = False,
        knee_band: float = 0.0,
        knee_step: float = 0.01,
        queueing_budget_s: float = 0.0,
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
        if not min_coef >= 0:
            raise ConstraintError(f"min_coef must be >= 0, got {min_coef}")
        if not backlog_clip >= 1:
            raise ConstraintError(f"backlog_clip must be >= 1, got {backlog_clip}")
        if not queueing_budget_s >= 0:
            raise ConstraintError(f"queueing_budget_s must be >= 0, got {queueing_budget_s}")
        self.queueing_budget_s = float(queueing_budget_s)
        self.min_coef = float(min_coef)
        self.backlog_clip = float(backlog_clip)
        self.use_weighted = bool(use_weighted)
        if not knee_band >= 0:
            raise ConstraintError(f"knee_band must be >= 0, got {knee_band}")
        if not 0 < knee_step <= 1:
            raise ConstraintError(f"knee_step must be in (0, 1], got {knee_step}")
        self.knee_band = float(knee_band)
        self.knee_step = float(knee_step)
        self.knee_bytes_per_s: float | None = None
        """The most goodput the link delivered in the last congestion episode (Δ > α)."""
        self._episode: tuple[float, float, float] | None = None
        """The congestion episode under way: (start t, peak goodput, ξ when it began)."""
        self._calm_goodput = 0.0
        self._calm_since = 0.0
        if not alpha_bytes_per_s > 0:
            raise ConstraintError(f"alpha_bytes_per_s must be > 0, got {alpha_bytes_per_s}")
        if not learning_rate > 0:
            raise ConstraintError(f"learning_rate must be > 0, got {learning_rate}")
        if not 0 <= min_bytes_per_s <= max_bytes_per_s:
            raise ConstraintError(
                f"need 0 <= min_bytes_per_s ({min_bytes_per_s}) <= max_bytes_per_s "
                f"({max_bytes_per_s})"
            )
        if not scale_bytes_per_s > 0:
            raise ConstraintError(f"scale_bytes_per_s must be > 0, got {scale_bytes_per_s}")
        for name, value in (
            ("initial_coef", initial_coef),
            ("initial_intercept_bytes_per_s", initial_intercept_bytes_per_s),
        ):
            if not math.isfinite(value):
                raise ConstraintError(f"{name} must be finite, got {value}")
        self.alpha_bytes_per_s = float(alpha_bytes_per_s)
        self.alpha_now_bytes_per_s = self.alpha_bytes_per_s
        """α as of the last learned window (above ``alpha_bytes_per_s`` only with
        ``queueing_budget_s``): ξ = R(α_now)."""
        self.min_bytes_per_s = float(min_bytes_per_s)
        self.max_bytes_per_s = float(max_bytes_per_s)
        self.scale_bytes_per_s = float(scale_bytes_per_s)
        # Imported here, not with the module: scikit-learn pulls in scipy.stats (1.5 s on the
        # test VM, several on a Pi), which a config check or a link-statistics constraint
        # (the peers' LinkStatsConstraint) never needs.
        from sklearn.linear_model import SGDRegressor

        self.model: SGDRegressor = SGDRegressor(
            loss="squared_error",
            penalty=None,
            learning_rate="constant",
            eta0=learning_rate,
            shuffle=False,
            fit_intercept=True,
        )
        # partial_fit has no coef_init: allocate with a step on (0, 0), which leaves the zero
        # model unchanged (zero residual), then set the initial belief.
        self.model.partial_fit(np.zeros((1, 1)), np.zeros(1))
        self.model.coef_ = np.array([max(float(initial_coef), self.min_coef)])
        self.model.intercept_ = np.array([initial_intercept_bytes_per_s / scale_bytes_per_s])

    @property
    def coef(self) -> float:
        """Current slope dR/dΔ (dimensionless)."""
        return float(self.model.coef_[0])

    @property
    def intercept_bytes_per_s(self) -> float:
        """Current R(0) in bytes per second."""
        return float(self.model.intercept_[0]) * self.scale_bytes_per_s

    def predict_bytes_per_s(self, backlog_bytes_per_s: float) -> float:
        """R_t(Δ): the modelled goodput at backlog Δ, unclamped."""
        return self.intercept_bytes_per_s + self.coef * backlog_bytes_per_s

    def limit_bytes_per_s(self, *, now: float) -> float:
        """ξ(t) = R_t(α) clamped to [min, max] (eq. 6.7)."""
        del now
        xi = self.predict_bytes_per_s(self.alpha_now_bytes_per_s)
        if not math.isfinite(xi):
            return self.min_bytes_per_s
        return min(self.max_bytes_per_s, max(self.min_bytes_per_s, xi))

    def apply_params(self, checked: Mapping[str, float]) -> None:
        super().apply_params(checked)
        if self.queueing_budget_s == 0:  # ξ = R(α) at once, not from the next learned window
            self.alpha_now_bytes_per_s = self.alpha_bytes_per_s

    def alpha_for(self, o: WindowStats) -> float:
        """α for window ``o``: the fixed α, or the backlog ``queueing_budget_s`` makes."""
        if self.queueing_budget_s == 0:
            return self.alpha_bytes_per_s
        divisor = max(o.base_latency_s, self.stats.min_base_latency_s)
        return max(self.alpha_bytes_per_s,
                   o.goodput_bytes_per_s * self.queueing_budget_s / divisor)

    def _learn(self, observations: list[WindowStats]) -> None:
        # One epoch of plain SGD over the batch, in order: one step per observation.
        scale = self.scale_bytes_per_s
        x = np.array(
            [[min(o.backlog_bytes_per_s, self.backlog_clip * self.alpha_for(o)) / scale]
             for o in observations],
            dtype=np.float64,
        )
        y = np.array([o.goodput_bytes_per_s / scale for o in observations], dtype=np.float64)
        xi_before = self.limit_bytes_per_s(now=0.0)  # ξ does not depend on now here
        weight = self._step_weights(observations, xi_before)
        if weight is not None and not weight.any():
            return  # the application sent nothing in these windows: nothing to learn
        coef, intercept = self.model.coef_.copy(), self.model.intercept_.copy()
        self.model.partial_fit(x, y, sample_weight=weight)
        if not (np.all(np.isfinite(self.model.coef_)) and np.isfinite(self.model.intercept_[0])):
            # A divergent step (learning rate too high for this noise) must not poison ξ.
            self.model.coef_, self.model.intercept_ = coef, intercept
        if self.model.coef_[0] < self.min_coef:
            # Projected SGD onto increasing models: see the class docstring.
            self.model.coef_[0] = self.min_coef
        self.alpha_now_bytes_per_s = self.alpha_for(observations[-1])
        if self.knee_band > 0 and self._episode is not None:
            # A new congestion episode takes ξ to just under what the link delivered, not
            # further, until it has lasted KNEE_HOLD_WINDOWS (then the link really has less).
            start, peak, xi_start = self._episode
            if observations[-1].t_end - start <= KNEE_HOLD_WINDOWS * self.window_s:
                floor = min((1 - self.knee_band) * min(peak, xi_start), xi_before)
                xi = self.predict_bytes_per_s(self.alpha_now_bytes_per_s)
                if xi < floor:
                    self.model.intercept_[0] += (floor - xi) / scale

    def _step_weights(self, observations: list[WindowStats], xi: float) -> np.ndarray | None:
        """Per-observation SGD step weights (None: equal steps, the thesis' SGD)."""
        if not self.use_weighted and self.knee_band == 0:
            return None
        xi = max(xi, 1e-9)
        weight = np.ones(len(observations))
        for i, o in enumerate(observations):
            if o.backlog_bytes_per_s > self.alpha_for(o):
                # Congested: a full step; the episode's peak goodput is where the knee is.
                if self._episode is None:
                    # The window that shows congestion first has already lost goodput: the
                    # rate the link carried is the last calm window's.
                    peak = max(o.goodput_bytes_per_s, self._calm_goodput)
                    self._episode = (o.t_end, peak, xi)
                else:
                    start, peak, xi_start = self._episode
                    self._episode = (start, max(peak, o.goodput_bytes_per_s), xi_start)
                continue
            if self._episode is not None:
                self.knee_bytes_per_s = self._episode[1]
                self._episode = None
                self._calm_since = o.t_end
            self._calm_goodput = o.goodput_bytes_per_s
            if self.use_weighted:
                weight[i] = min(1.0, o.goodput_bytes_per_s / xi)
            if self.knee_band > 0 and self.knee_bytes_per_s is not None:
                # The knee is forgotten over KNEE_FORGET_WINDOWS calm windows: a congestion
                # episode from a latency glitch must not slow ξ for good.
                distance = max(abs(xi - self.knee_bytes_per_s) / (
                    self.knee_band * max(self.knee_bytes_per_s, 1e-9)),
                    (o.t_end - self._calm_since) / (KNEE_FORGET_WINDOWS * self.window_s))
                weight[i] *= self.knee_step + (1 - self.knee_step) * min(1.0, distance) ** 2
        return weight
