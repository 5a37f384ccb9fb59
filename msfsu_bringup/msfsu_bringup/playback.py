"""When each message of a bag is due on the wall clock, at a playback rate that may change while playing (ROS-free)."""

from __future__ import annotations


def _positive(rate: float) -> float:
    if rate <= 0:
        raise ValueError(f"playback rate must be positive, got {rate}")
    return rate


class PlaybackSchedule:
    """Bag time -> wall time (both ns): bag time runs `rate` times as fast as wall time from an origin pair.

    A new rate takes effect at the wall time it is set: the bag time the schedule had reached then stays where it is,
    and the rest of the bag is due at the new rate from there (no jump either way).
    """

    def __init__(self, bag_start_ns: int, wall_start_ns: int, rate: float) -> None:
        self.bag_origin_ns: float = bag_start_ns
        self.wall_origin_ns: float = wall_start_ns
        self.rate = _positive(rate)

    def due_ns(self, bag_time_ns: int) -> float:
        """Wall time at which the message recorded at `bag_time_ns` is due."""
        return self.wall_origin_ns + (bag_time_ns - self.bag_origin_ns) / self.rate

    def bag_time_ns(self, wall_ns: int) -> float:
        """The bag time the schedule has reached at `wall_ns`."""
        return self.bag_origin_ns + (wall_ns - self.wall_origin_ns) * self.rate

    def set_rate(self, rate: float, wall_ns: int) -> None:
        self.bag_origin_ns, self.wall_origin_ns, self.rate = self.bag_time_ns(wall_ns), wall_ns, _positive(rate)
