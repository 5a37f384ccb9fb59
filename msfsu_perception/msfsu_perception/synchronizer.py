"""Approximate-time pairing of two sensor streams (message_filters is not available as a wheel).

Each stream keeps a bounded queue of (stamp, item). A new item is paired with the closest-in-time
queued item of the other stream if they are within `slop`; the pair and everything queued before
it are removed (older items could only pair out of order). Items that never make it into a pair
are counted by reason (duplicate / out-of-order stamp, unpaired), so a node can report them.
"""

from __future__ import annotations

from collections import Counter, deque
from typing import Any, Generic, NamedTuple, TypeVar

A = TypeVar("A")
B = TypeVar("B")


class Pair(NamedTuple, Generic[A, B]):
    stamp_ns: int  # stamp of the "a" item (the camera frame)
    a: A
    b: B


class ApproximateTimeSynchronizer(Generic[A, B]):
    """Pairs items of streams "a" and "b" by stamp (integer nanoseconds)."""

    def __init__(self, queue_size: int = 10, slop_ns: int = 50_000_000) -> None:
        if queue_size < 1 or slop_ns < 0:
            raise ValueError("queue_size must be >= 1 and slop >= 0")
        self.queue_size = queue_size
        self.slop_ns = slop_ns
        self.dropped: Counter[str] = Counter()
        self._queues: dict[str, deque[tuple[int, Any]]] = {"a": deque(), "b": deque()}
        self._last_stamp: dict[str, int | None] = {"a": None, "b": None}

    def add_a(self, stamp_ns: int, item: A) -> Pair[A, B] | None:
        match = self._add("a", "b", stamp_ns, item)
        return None if match is None else Pair(stamp_ns, item, match[1])

    def add_b(self, stamp_ns: int, item: B) -> Pair[A, B] | None:
        match = self._add("b", "a", stamp_ns, item)
        return None if match is None else Pair(match[0], match[1], item)

    def clear(self) -> None:
        """Forget the unpaired items and the last stamps, as a new synchronizer would (a stream that starts again
        may start earlier); the drop counters stay."""
        for name in self._queues:
            self._queues[name].clear()
            self._last_stamp[name] = None

    def _add(self, name: str, other_name: str, stamp_ns: int, item: Any) -> tuple[int, Any] | None:
        last = self._last_stamp[name]
        if last is not None and stamp_ns <= last:
            self.dropped[f"{'duplicate' if stamp_ns == last else 'out_of_order'}_stamp_{name}"] += 1
            return None
        self._last_stamp[name] = stamp_ns
        queue, other = self._queues[name], self._queues[other_name]
        best = min(range(len(other)), key=lambda i: abs(other[i][0] - stamp_ns), default=None)
        if best is not None and abs(other[best][0] - stamp_ns) <= self.slop_ns:
            self._drop_unpaired(other, best, other_name)
            match = other.popleft()
            self._drop_unpaired(queue, len(queue), name)
            return match
        queue.append((stamp_ns, item))
        if len(queue) > self.queue_size:
            self._drop_unpaired(queue, 1, name)
        return None

    def _drop_unpaired(self, queue: deque, count: int, name: str) -> None:
        for _ in range(count):
            queue.popleft()
        if count:
            self.dropped[f"unpaired_{name}"] += count
