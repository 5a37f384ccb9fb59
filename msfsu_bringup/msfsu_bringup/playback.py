"""When each message of a bag is due on the wall clock, at a playback rate that may change and with pauses while
playing (ROS-free)."""

from __future__ import annotations

import math


def _positive(rate: float) -> float:
    if rate <= 0:
        raise ValueError(f"playback rate must be positive, got {rate}")
    return rate


class PlaybackSchedule:
    """Bag time -> wall time (both ns): bag time runs `rate` times as fast as wall time from an origin pair.

    A new rate takes effect at the wall time it is set: the bag time the schedule had reached then stays where it is,
    and the rest of the bag is due at the new rate from there (no jump either way). A pause stops the bag's time at
    the wall time it is paused: nothing is due until it resumes, and the rest of the bag is due as much later as the
    pause was long (nothing is skipped).
    """

    def __init__(self, bag_start_ns: int, wall_start_ns: int, rate: float) -> None:
        self.bag_origin_ns: float = bag_start_ns
        self.wall_origin_ns: float = wall_start_ns
        self.rate = _positive(rate)
        self.paused_at_ns: int | None = None

    @property
    def paused(self) -> bool:
        return self.paused_at_ns is not None

    def due_ns(self, bag_time_ns: int) -> float:
        """Wall time at which the message recorded at `bag_time_ns` is due (never, while paused)."""
        if self.paused:
            return math.inf
        return self.wall_origin_ns + (bag_time_ns - self.bag_origin_ns) / self.rate

    def bag_time_ns(self, wall_ns: int) -> float:
        """The bag time the schedule has reached at `wall_ns` (where it stopped, while paused)."""
        if self.paused:
            wall_ns = min(wall_ns, self.paused_at_ns)
        return self.bag_origin_ns + (wall_ns - self.wall_origin_ns) * self.rate

    def set_rate(self, rate: float, wall_ns: int) -> None:
        self.bag_origin_ns, self.wall_origin_ns, self.rate = self.bag_time_ns(wall_ns), wall_ns, _positive(rate)
        if self.paused:
            self.paused_at_ns = wall_ns

    def pause(self, wall_ns: int) -> None:
        """Stop the bag's time at `wall_ns` (a pause that is one already stays as it was)."""
        if not self.paused:
            self.paused_at_ns = wall_ns

    def resume(self, wall_ns: int) -> None:
        """Let the bag's time run again from where it stopped."""
        if self.paused:
            self.wall_origin_ns += wall_ns - self.paused_at_ns
            self.paused_at_ns = None
