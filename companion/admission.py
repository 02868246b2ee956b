"""How many connections one address, and everyone, may hold open: one sans-I/O gate for
every listening service (the companion's ``/peers``, the ground station's HTTP connections and
its dashboard WebSockets), so a host on the network cannot take every slot and lock the
others out, and the three services count, refuse and log alike.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field
from typing import Literal

__all__ = ["ConnectionGate", "Refusal", "worth_logging"]


def worth_logging(count: int) -> bool:
    """Log the 1st, 10th, 100th and every 1000th of a repeated event: a flood of connections
    must not become a flood of log lines, and the count still shows how big it is."""
    return count in (1, 10, 100) or (count > 0 and count % 1000 == 0)


@dataclass(frozen=True, slots=True)
class Refusal:
    """Why a connection was not admitted."""

    reason: Literal["client", "total"]
    """``client``: that address holds ``cap`` already; ``total``: ``cap`` are open in all."""
    client: str
    cap: int
    refused: int
    """Refusals of this reason so far, this one included."""

    @property
    def worth_logging(self) -> bool:
        return worth_logging(self.refused)


@dataclass
class ConnectionGate:
    """Connections open per client address, at most ``max_per_client`` each and
    ``max_total`` in all. Every admitted connection must be released exactly once."""

    max_total: int
    max_per_client: int
    open_by_client: Counter[str] = field(default_factory=Counter)
    refused: Counter[str] = field(default_factory=Counter)
    """Refusals so far, by reason (``client``, ``total``)."""

    def __post_init__(self) -> None:
        if self.max_total < 1 or self.max_per_client < 1:
            raise ValueError(f"a connection gate must admit at least one connection "
                             f"(max_total={self.max_total}, max_per_client="
                             f"{self.max_per_client})")

    @property
    def open(self) -> int:
        return sum(self.open_by_client.values())

    def admit(self, client: str) -> Refusal | None:
        """None (and the connection counted), or why it is refused."""
        if self.open_by_client[client] >= self.max_per_client:
            return self._refuse("client", client, self.max_per_client)
        if self.open >= self.max_total:
            return self._refuse("total", client, self.max_total)
        self.open_by_client[client] += 1
        return None

    def release(self, client: str) -> None:
        left = self.open_by_client[client] - 1
        if left < 0:
            raise ValueError(f"{client} released a connection it did not hold")
        if left:
            self.open_by_client[client] = left
        else:
            del self.open_by_client[client]

    def _refuse(self, reason: Literal["client", "total"], client: str, cap: int) -> Refusal:
        self.refused[reason] += 1
        return Refusal(reason, client, cap, self.refused[reason])
