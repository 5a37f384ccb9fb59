"""Where on a benchmark route a step lies: the junction phase, the metres into the junction, the side of the route.

A route is the polyline the simulator's route tracker follows (msfsu_sim.route: 2 m poses on the spawn lane, each
with its RoadOption); a junction is a run of poses whose option is not LANE_FOLLOW (RouteTracker.junction_spans).
Around junction i with span [start, end):

- `approach`: start - LOOKAHEAD_M <= progress < start (the command is already announced, the car is not in yet);
- `in`: start <= progress < end;
- `after`: end <= progress < end + AFTER_M (the exit, where the command is LANE_FOLLOW again);
- `away`: anywhere else.

`into_m` is progress - start: negative on the approach, the metres driven into the junction inside it. Progress is
the route tracker's (the arc length of the car's projection, searched forwards only), replayed on the trajectory,
so it is the progress the simulator recorded. The side: the car's signed distance from the route's polyline,
positive right (as steer and bearing are), so a LEFT turn cut short reads negative.

Pure functions, except `load_route_lines`, which builds each town's map in a render-free MetaDrive (seconds a
town) and caches the polylines.
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from msfsu_control.route_tracker import RouteTracker, RouteTrackerConfig

LOOKAHEAD_M = RouteTrackerConfig().lookahead_m  # the route node announces a junction's command this far ahead
AFTER_M = 15.0  # the junction's exit, counted as its own phase
PHASES = ("approach", "in", "after", "away")


@dataclass(frozen=True)
class Place:
    phase: str  # one of PHASES
    junction: int | None  # index of the junction span (None: away)
    into_m: float | None  # progress - the junction's start (None: away)


def junction_place(progress_m: float, spans: Sequence[tuple[float, float]], lookahead_m: float = LOOKAHEAD_M,
                   after_m: float = AFTER_M) -> Place:
    """The Place of a route progress: inside a junction first, then on the approach of the next one, then on the exit
    of the last one before it, else away."""
    for index, (start, end) in enumerate(spans):
        if start <= progress_m < end:
            return Place("in", index, progress_m - start)
    for index, (start, _) in enumerate(spans):
        if start - lookahead_m <= progress_m < start:
            return Place("approach", index, progress_m - start)
    for index in reversed(range(len(spans))):
        start, end = spans[index]
        if end <= progress_m < end + after_m:
            return Place("after", index, progress_m - start)
    return Place("away", None, None)


@dataclass(frozen=True)
class RouteLine:
    """A route's polyline and each pose's RoadOption value (msfsu_sim.route.Route)."""

    points: np.ndarray  # (N, 2)
    options: np.ndarray  # (N,) RoadOption values

    def tracker(self) -> RouteTracker:
        return RouteTracker(self.points, self.options, RouteTrackerConfig())

    def spans(self) -> list[tuple[float, float]]:
        return self.tracker().junction_spans()

    def junction_options(self) -> list[int]:
        """The RoadOption value of each junction span, in order."""
        tracker, cumulative = self.tracker(), _cumulative(self.points)
        return [int(self.options[int(np.searchsorted(cumulative, start + 1e-6, side="right")) - 1])
                for start, _ in tracker.junction_spans()]


def _cumulative(points: np.ndarray) -> np.ndarray:
    return np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(points, axis=0), axis=1))])


@dataclass(frozen=True)
class Followed:
    """A trajectory replayed along its route: per step."""

    progress_m: np.ndarray  # the route tracker's progress
    offset_m: np.ndarray  # signed distance from the polyline at that progress, positive right
    heading_error_rad: np.ndarray  # the car's yaw minus the route's heading there (counter-clockwise: left)


def follow(line: RouteLine, xy: np.ndarray, yaw: np.ndarray) -> Followed:
    """Replay the route tracker on the trajectory's positions (map frame; yaw counter-clockwise, rad)."""
    tracker = line.tracker()
    points = np.asarray(line.points, np.float64)
    cumulative = _cumulative(points)
    vectors = np.diff(points, axis=0)
    progress = np.empty(len(xy))
    offset = np.empty(len(xy))
    heading = np.empty(len(xy))
    for step, (x, y) in enumerate(np.asarray(xy, np.float64)):
        tracker.update(float(x), float(y))
        progress[step] = tracker.progress_m
        segment = min(max(int(np.searchsorted(cumulative, tracker.progress_m, side="right")) - 1, 0), len(vectors) - 1)
        direction = vectors[segment] / max(float(np.linalg.norm(vectors[segment])), 1e-12)
        relative = np.array([x, y]) - tracker.point_at(tracker.progress_m)
        offset[step] = -(direction[0] * relative[1] - direction[1] * relative[0])  # left of the line: negative
        heading[step] = math.atan2(direction[1], direction[0])
    error = (np.asarray(yaw, np.float64) - heading + math.pi) % (2 * math.pi) - math.pi
    return Followed(progress, offset, error)


def turn_in_m(into_m: np.ndarray, heading_change_rad: np.ndarray, toward: int, degrees: float) -> float | None:
    """The metres into the junction (into_m of the step) where the car's heading has first turned `degrees` toward
    the turn (toward: +1 left, counter-clockwise; -1 right) since the approach began; None if it never did."""
    reached = np.flatnonzero(toward * np.asarray(heading_change_rad) >= math.radians(degrees))
    return None if not len(reached) else float(np.asarray(into_m)[reached[0]])


def unwrap_from(yaw: np.ndarray, reference: float) -> np.ndarray:
    """The heading change since `reference` (rad, counter-clockwise), continuous along the steps."""
    return np.unwrap(np.concatenate([[reference], np.asarray(yaw, np.float64)]))[1:] - reference


def bin_means(values: np.ndarray, positions: np.ndarray, edges: Sequence[float]) -> list[float | None]:
    """Mean of `values` per bin [edges[i], edges[i + 1]) of `positions` (None where a bin holds none)."""
    means = []
    for low, high in zip(edges[:-1], edges[1:]):
        inside = (positions >= low) & (positions < high) & np.isfinite(values)
        means.append(float(values[inside].mean()) if inside.any() else None)
    return means


def lead_lag_steps(network: np.ndarray, expert: np.ndarray, max_lag: int) -> int | None:
    """The shift k (steps, |k| <= max_lag) that best lines the network's steer up with the expert's label:
    argmax over k of the correlation of network[t] and expert[t + k]. k > 0: the network does now what the expert's
    label says k steps later (it leads); None for series too short or without spread."""
    network, expert = np.asarray(network, np.float64), np.asarray(expert, np.float64)
    best, best_corr = None, -np.inf
    if len(network) != len(expert) or len(network) < 3 * max_lag:
        return None
    for lag in range(-max_lag, max_lag + 1):
        a = network[max(0, -lag): len(network) - max(0, lag)]
        b = expert[max(0, lag): len(expert) - max(0, -lag)]
        keep = np.isfinite(a) & np.isfinite(b)
        if keep.sum() < max_lag + 3 or a[keep].std() < 1e-6 or b[keep].std() < 1e-6:
            continue
        corr = float(np.corrcoef(a[keep], b[keep])[0, 1])
        if corr > best_corr:
            best, best_corr = lag, corr
    return best


# ----- the route polylines, from the towns' maps -----
def _route_id(route) -> str:
    return f"{route.town}|{route.start[0]}|{route.start[1]}|{route.lane}|{route.destination}"


def load_route_lines(routes: Sequence, cache: Path) -> dict[str, RouteLine]:
    """{route key: RouteLine} of benchmark routes (closed_loop.suites.BenchmarkRoute), as the simulator plans them
    (MetaDrive's shortest path from the spawn lane to the destination, sampled on the spawn lane's index). Polylines
    already in `cache` (JSON, keyed by town, start, lane and destination) are not built again."""
    stored = json.loads(cache.read_text()) if cache.exists() else {}
    missing = sorted({route.town for route in routes if _route_id(route) not in stored})
    for town in missing:
        stored.update(_town_lines(town, [route for route in routes if route.town == town]))
        cache.parent.mkdir(parents=True, exist_ok=True)
        cache.write_text(json.dumps(stored))
    return {route.key: RouteLine(np.asarray(stored[_route_id(route)]["points"], np.float64),
                                 np.asarray(stored[_route_id(route)]["options"], np.uint8)) for route in routes}


def _town_lines(town: str, routes: Sequence) -> dict[str, dict]:
    from metadrive.envs.metadrive_env import MetaDriveEnv

    from msfsu_sim.route import route_from_checkpoints
    from msfsu_sim.route_catalog import map_config
    from msfsu_sim.scenarios import TOWNS

    spec = TOWNS[town]
    env = MetaDriveEnv(dict(map_config=map_config(spec), start_seed=spec.map_seed, num_scenarios=1,
                            use_render=False, log_level=40, traffic_density=0.0, random_spawn_lane_index=False))
    lines = {}
    try:
        env.reset(seed=spec.map_seed)
        network = env.engine.current_map.road_network
        for route in routes:
            checkpoints = network.shortest_path((route.start[0], route.start[1], route.lane), route.destination)
            planned = route_from_checkpoints(network.graph, checkpoints, route.lane)
            lines[_route_id(route)] = {"points": np.round(planned.poses[:, :2], 3).tolist(),
                                       "options": planned.options.astype(int).tolist()}
    finally:
        env.close()
    return lines
