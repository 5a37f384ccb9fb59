"""A one-item mailbox between sensor callbacks and inference.

Putting replaces whatever is waiting (and reports it, so the node can count skipped frames): inference
always works on the newest pair and a slow model never builds a backlog. Thread-safe, never blocks.
"""

from __future__ import annotations

import threading
from typing import Generic, TypeVar

T = TypeVar("T")


class LatestSlot(Generic[T]):
    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._item: T | None = None

    def put(self, item: T) -> T | None:
        """Store `item`; return the item it replaced (skipped), if any."""
        with self._lock:
            replaced, self._item = self._item, item
            return replaced

    def take(self) -> T | None:
        """Remove and return the waiting item (None when empty)."""
        with self._lock:
            item, self._item = self._item, None
            return item
