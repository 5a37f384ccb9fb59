"""Progress along a global route and the navigation command it implies (ROS-free).

The route is a polyline of poses, each carrying the RoadOption of the segment that starts at it
(CARLA's global planner labels junction waypoints LEFT/RIGHT/STRAIGHT, the rest LANE_FOLLOW).
Progress is the arc length of the vehicle's projection onto the polyline, searched only forwards
within a window so it never jumps backwards and survives lateral deviation and loops in the route.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from msfsu_common.road_option import RoadOption, parse_road_option
from msfsu_common.settings import setting


@dataclass(frozen=True)
class RouteTrackerConfig:
    lookahead_m: float = setting(15.0, "announce a junction option this far ahead, m", 0.0, 500.0, name="lookahead")
    # how far ahead of the current progress a projection may land
    search_window_m: float = setting(30.0, "max forward progress jump per update, m", 1.0, 1000.0,
                                     name="search_window")


class RouteTracker:
    """Progress and command on one route; `config` may be replaced between updates (the next update uses it)."""

    def __init__(self, points: np.ndarray, options: np.ndarray, config: RouteTrackerConfig = RouteTrackerConfig()):
        points = np.asarray(points, dtype=np.float64)
        if points.ndim != 2 or points.shape[1] != 2 or len(points) < 2:
            raise ValueError(f"route needs at least 2 points of (x, y), got shape {points.shape}")
        if len(options) != len(points):
            raise ValueError(f"{len(options)} options for {len(points)} route points")
        self.options = [parse_road_option(value) for value in options]
        self.config = config
        self._starts = points[:-1]
        self._vectors = np.diff(points, axis=0)
        self._lengths = np.linalg.norm(self._vectors, axis=1)
        self._cumulative = np.concatenate([[0.0], np.cumsum(self._lengths)])
        self.progress_m = 0.0

    @property
    def length_m(self) -> float:
        return float(self._cumulative[-1])

    def update(self, x: float, y: float) -> RoadOption:
        """Advance progress with the vehicle position and return the command to drive now."""
        self.progress_m = self._project(np.array([x, y], dtype=np.float64))
        return self.command()

    def command(self) -> RoadOption:
        """First junction option within the look-ahead (including the segment we are on), else LANE_FOLLOW."""
        current = self._segment_at(self.progress_m)
        last = self._segment_at(min(self.progress_m + self.config.lookahead_m, self.length_m))
        for index in range(current, last + 1):
            if self.options[index] is not RoadOption.LANE_FOLLOW:
                return self.options[index]
        return RoadOption.LANE_FOLLOW

    def junction_spans(self) -> list[tuple[float, float]]:
        """(start, end) arc lengths of each run of junction segments (options other than LANE_FOLLOW), in order."""
        spans: list[tuple[float, float]] = []
        start = None
        for index, option in enumerate(self.options[:-1]):
            inside = option is not RoadOption.LANE_FOLLOW
            if inside and start is None:
                start = float(self._cumulative[index])
            elif not inside and start is not None:
                spans.append((start, float(self._cumulative[index])))
                start = None
        if start is not None:
            spans.append((start, self.length_m))
        return spans

    def option_at(self, arc_length: float) -> RoadOption:
        """The option of the segment at `arc_length` metres from the route's start (clamped to the route)."""
        return self.options[self._segment_at(arc_length)]

    def point_at(self, arc_length: float) -> np.ndarray:
        """(x, y) of the route at `arc_length` metres from its start (clamped to the route)."""
        arc_length = min(max(arc_length, 0.0), self.length_m)
        index = self._segment_at(arc_length)
        fraction = (arc_length - self._cumulative[index]) / max(self._lengths[index], 1e-12)
        return self._starts[index] + min(fraction, 1.0) * self._vectors[index]

    def _segment_at(self, arc_length: float) -> int:
        index = int(np.searchsorted(self._cumulative, arc_length, side="right")) - 1
        return min(max(index, 0), len(self._lengths) - 1)

    def _project(self, position: np.ndarray) -> float:
        first = self._segment_at(self.progress_m)
        last = self._segment_at(self.progress_m + self.config.search_window_m)
        starts, vectors = self._starts[first : last + 1], self._vectors[first : last + 1]
        lengths_sq = np.maximum(np.einsum("ij,ij->i", vectors, vectors), 1e-12)
        t = np.clip(np.einsum("ij,ij->i", position - starts, vectors) / lengths_sq, 0.0, 1.0)
        distances = np.linalg.norm(starts + t[:, None] * vectors - position, axis=1)
        best = int(np.argmin(distances))
        arc = self._cumulative[first + best] + t[best] * self._lengths[first + best]
        return max(float(arc), self.progress_m)
