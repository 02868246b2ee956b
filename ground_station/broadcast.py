"""Dashboard push: one bounded queue per WebSocket client, dropping the oldest update.

The receiver calls :meth:`Broadcaster.publish` synchronously (no await), so a slow browser
can never stall the UDP path or other browsers; each client's writer task drains its own
queue and counts what it had to drop.
"""

from __future__ import annotations

import asyncio
import json
from collections.abc import Mapping
from typing import Any

__all__ = ["Broadcaster", "ClientQueue"]


class ClientQueue:
    """Pending updates of one browser; full means the oldest update is discarded."""

    def __init__(self, maxsize: int) -> None:
        self.queue: asyncio.Queue[str] = asyncio.Queue(maxsize=maxsize)
        self.dropped = 0

    def put(self, text: str) -> None:
        while True:
            try:
                self.queue.put_nowait(text)
                return
            except asyncio.QueueFull:
                try:
                    self.queue.get_nowait()
                    self.dropped += 1
                except asyncio.QueueEmpty:  # pragma: no cover - cannot be full and empty
                    pass


class Broadcaster:
    """Fans out JSON updates to every registered client queue."""

    def __init__(self, *, queue_size: int) -> None:
        self.queue_size = queue_size
        self.clients: set[ClientQueue] = set()
        self.published = 0

    def register(self) -> ClientQueue:
        client = ClientQueue(self.queue_size)
        self.clients.add(client)
        return client

    def unregister(self, client: ClientQueue) -> None:
        self.clients.discard(client)

    def publish(self, kind: str, payload: Mapping[str, Any]) -> None:
        if not self.clients:
            return
        text = json.dumps({"kind": kind, **payload}, allow_nan=False, default=str)
        self.published += 1
        for client in self.clients:
            client.put(text)

    @property
    def dropped(self) -> int:
        return sum(c.dropped for c in self.clients)
