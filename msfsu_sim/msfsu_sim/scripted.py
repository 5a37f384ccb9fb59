"""Scripted traffic participants of the per-ability scenarios: one actor, one conflict with the ego, on cue.

A scenario (msfsu_sim.scenario_spec.ScenarioSpec) places one actor relative to the ego's route and lets it act when
the ego comes: a pedestrian crossing the road from the left or right kerb, a pedestrian stepping out in front of a car
parked in the right lane, a lead car that brakes hard, a car that cuts in from the right lane and slows, a car
crossing a junction on the ego's path that does not yield (it has the right of way), or nothing at all (a clear road
of the same shape: the control for false stops). Bench2Drive's abilities, on MetaDrive's maps.

Where: positions are (arc length along the ego's route, lateral offset) along the route's lane 0 (PathFrame;
lateral positive towards the outer lanes and the right kerb). Arc lengths run from the start of the route's first
road, as RouteTracker's progress (the benchmark's) does.

When: a pedestrian or a crossing car starts when the ego, at its current speed (at least CUE_SPEED_MPS), would
reach the conflict point within the actor's own time to get there plus the scenario's `timing_s`: a slow car meets
the actor as a fast one does, and the scenario stays a conflict whatever the driver's speed. The lead car brakes
when it reaches its braking point; the cutting car moves over once it is `gap_m` ahead of the ego's bumper.
Everything after the cue is a fixed function of time and nothing is random at run time: the same spec gives the same
actor placement and motion, and with the same driver the same episode.

Vehicles are moved kinematically (position, heading and velocity set every step along their path, as MetaDrive's
log replay moves recorded traffic); pedestrians walk by velocity, as msfsu_sim.pedestrians' crossers do.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from metadrive.manager.base_manager import BaseManager

from msfsu_sim.route import block_of, edge_lane_option, is_junction_edge
from msfsu_sim.scene import EGO_HALF_LENGTH_M
from msfsu_sim.scenario_spec import (CLEAR_ROAD, CROSSING_TRAFFIC, CUT_IN, LEAD_BRAKING, PEDESTRIAN_BEHIND_PARKED_CAR,
                                     PEDESTRIAN_CROSSING, ScenarioSpec)

CUE_SPEED_MPS = 2.0  # the ego's speed used for its time to the conflict point is at least this
LANE_WIDTH_M = 3.5
KERB_M = LANE_WIDTH_M / 2 + 0.5  # beyond the outer lane's edge: where a pedestrian waits
STEP_S = 0.1  # one simulator step (msfsu_sim.environment.STEP_S; not imported: environment imports this module)
RESUME_ACCEL = 2.0  # m/s^2, a stopped car driving off again
PARKED_LENGTH_M = 4.5  # about the parked car's length (MetaDrive's sedans are 4.3-4.9 m)


class PathFrame:
    """A path along MetaDrive lanes: (arc length, lateral offset) -> map position and heading.

    Arc lengths run from the start of the first lane; beyond either end the path goes on straight along the end's
    heading. Lateral offsets are MetaDrive's: positive towards the outer lanes (the right kerb)."""

    def __init__(self, lanes: list[Any]) -> None:
        if not lanes:
            raise ValueError("a path needs at least one lane")
        self.lanes = lanes
        self.starts = np.concatenate([[0.0], np.cumsum([lane.length for lane in lanes])])
        self.length_m = float(self.starts[-1])

    def _at(self, arc: float) -> tuple[Any, float]:
        index = int(np.clip(np.searchsorted(self.starts, arc, side="right") - 1, 0, len(self.lanes) - 1))
        return self.lanes[index], arc - float(self.starts[index])

    def position(self, arc: float, lateral: float = 0.0) -> np.ndarray:
        if arc < 0.0 or arc > self.length_m:  # straight on beyond the ends
            end = min(max(arc, 0.0), self.length_m)
            base = self.position(end, lateral)
            heading = self.heading(end)
            return base + (arc - end) * np.array([math.cos(heading), math.sin(heading)])
        lane, s = self._at(arc)
        return np.asarray(lane.position(s, lateral), np.float64)

    def heading(self, arc: float) -> float:
        lane, s = self._at(min(max(arc, 0.0), self.length_m))
        return float(lane.heading_theta_at(min(max(s, 0.0), lane.length)))

    def project(self, xy: np.ndarray, near_m: float | None = None, window_m: float = 40.0) -> float:
        """The arc length of the path point nearest `xy` (searched within `window_m` of `near_m` when given)."""
        low, high = (0.0, self.length_m) if near_m is None else (near_m - window_m, near_m + window_m)
        arcs = np.arange(max(low, -50.0), min(high, self.length_m + 50.0) + 1e-9, 0.5)
        points = np.array([self.position(a) for a in arcs])
        return float(arcs[int(np.argmin(np.linalg.norm(points - np.asarray(xy)[:2], axis=1)))])


def route_lanes(graph: dict, checkpoints: list[str], lane_index: int = 0) -> list[Any]:
    """The lanes a route drives (lane `lane_index` of each road, clamped), as msfsu_sim.route samples them."""
    return [edge_lane_option(graph, a, b, lane_index)[0] for a, b in zip(checkpoints[:-1], checkpoints[1:])]


def side_sign(side: str) -> float:
    """Lateral sign of a side of the ego's lane: right is towards the outer lanes (positive)."""
    return 1.0 if side == "right" else -1.0


def kerb_offsets(lanes_each_way: int) -> tuple[float, float]:
    """Lateral offsets (from the centre of the ego's lane 0) of the left and right kerbs where pedestrians wait."""
    right = (lanes_each_way - 1) * LANE_WIDTH_M + KERB_M
    left = -(LANE_WIDTH_M / 2 + lanes_each_way * LANE_WIDTH_M + 0.5)
    return left, right


class _Actor:
    """One scripted participant: `update(time_s, ego)` once per step after the physics."""

    role = ""
    body: Any = None

    def update(self, time_s: float, ego_arc: float, ego_speed: float) -> None:
        raise NotImplementedError

    def plan(self, horizon_s: float = 5.0) -> np.ndarray | None:
        """(N, 2) where it will be over the next seconds (the expert's and the judge's prediction), None: unknown."""
        return None


def _eta(ego_arc: float, ego_speed: float, conflict_m: float) -> float:
    return (conflict_m - ego_arc) / max(ego_speed, CUE_SPEED_MPS)


class _Walker(_Actor):
    """Waits at `start`, walks to `end` once cued (the ego's time to the conflict <= its own + timing), stops there.

    Moved kinematically like the cars: MetaDrive's pedestrian body, given a velocity, covers about 0.8 of it."""

    def __init__(self, body: Any, role: str, start: np.ndarray, end: np.ndarray, enter_m: float, speed: float,
                 conflict_m: float, timing_s: float) -> None:
        self.body, self.role = body, role
        self.start, self.end, self.speed = start, end, speed
        self.length = float(np.linalg.norm(end - start))
        self.direction = (end - start) / self.length
        self.cue_s = enter_m / speed + timing_s  # its time to step into the ego's lane, shifted by the spec's timing
        self.conflict_m = conflict_m
        self.state, self.walked = "waiting", 0.0

    def update(self, time_s: float, ego_arc: float, ego_speed: float) -> None:
        if self.state == "waiting" and _eta(ego_arc, ego_speed, self.conflict_m) <= self.cue_s:
            self.state = "walking"
        elif self.state == "walking":
            self.walked = min(self.walked + self.speed * STEP_S, self.length)
            if self.walked >= self.length:
                self.state = "arrived"
        moving = self.state == "walking"
        self.body.set_position(tuple(self.start + self.walked * self.direction))
        self.body.set_velocity(list(self.direction), self.speed if moving else 0.0)

    def plan(self, horizon_s: float = 5.0) -> np.ndarray | None:
        return None  # constant velocity, as the expert and the judge predict every pedestrian


class _Driven(_Actor):
    """A car moved kinematically along a PathFrame: arc s(t), lateral l(t) given by `motion`."""

    def __init__(self, body: Any, role: str, path: PathFrame, arc: float, lateral: float, speed: float) -> None:
        self.body, self.role, self.path = body, role, path
        self.arc, self.lateral, self.speed = arc, lateral, speed
        self.lateral_rate = 0.0
        self._place()

    def _place(self) -> None:
        position = self.path.position(self.arc, self.lateral)
        heading = self.path.heading(self.arc)
        # a lane change turns the car towards where it moves
        heading += math.atan2(-self.lateral_rate, max(self.speed, 0.5)) * self._lateral_turn()
        self.body.set_position(tuple(position))
        self.body.set_heading_theta(heading)
        direction = np.array([math.cos(heading), math.sin(heading)])
        self.body.set_velocity(list(direction), self.speed)

    def _lateral_turn(self) -> float:
        """+1 or -1: the sign that turns the heading towards growing lateral offsets (MetaDrive's lateral axis)."""
        ahead = self.path.position(self.arc, 0.0)
        right = self.path.position(self.arc, 1.0) - ahead
        heading = self.path.heading(self.arc)
        left_normal = np.array([-math.sin(heading), math.cos(heading)])
        return 1.0 if float(np.dot(right, left_normal)) < 0 else -1.0

    def advance(self, acceleration: float, target: float) -> None:
        """One step towards `target` speed at `acceleration` (m/s^2, positive), then move."""
        change = acceleration * STEP_S
        self.speed = min(self.speed + change, target) if self.speed < target else max(self.speed - change, target)
        self.arc += self.speed * STEP_S

    def plan(self, horizon_s: float = 5.0) -> np.ndarray:
        arcs = self.arc + self.speed * np.arange(0.5, horizon_s + 1e-9, 0.5)
        return np.array([self.path.position(a, self.lateral) for a in arcs])


class _LeadCar(_Driven):
    """Drives ahead at its speed; brakes at `decel` once the ego is within `cue_m` of its braking point, stands for
    `hold_s`, then drives off."""

    def __init__(self, body: Any, path: PathFrame, arc: float, speed: float, brake_m: float, decel: float,
                 hold_s: float) -> None:
        super().__init__(body, "lead car braking hard", path, arc, 0.0, speed)
        self.cruise, self.brake_m, self.decel, self.hold_s = speed, brake_m, decel, hold_s
        self.state, self.stood_s = "cruising", 0.0

    def update(self, time_s: float, ego_arc: float, ego_speed: float) -> None:
        if self.state == "cruising" and self.arc >= self.brake_m:
            self.state = "braking"
        if self.state == "braking":
            self.advance(self.decel, 0.0)
            if self.speed <= 0.0:
                self.state = "standing"
        elif self.state == "standing":
            self.stood_s += STEP_S
            self.state = "leaving" if self.stood_s >= self.hold_s else "standing"
        else:
            self.advance(RESUME_ACCEL, self.cruise)
        self._place()


class _CuttingCar(_Driven):
    """Drives in the right lane faster than the ego; once `gap_m` ahead of the ego's bumper it moves into the ego's
    lane over CHANGE_S, then brakes to `slow` at `decel`, keeps that speed for `hold_s`, and speeds up again."""

    CHANGE_S = 1.5

    def __init__(self, body: Any, path: PathFrame, arc: float, speed: float, gap_m: float, decel: float,
                 slow: float, hold_s: float, car_half_length: float) -> None:
        super().__init__(body, "car cutting in", path, arc, LANE_WIDTH_M, speed)
        self.cruise, self.gap_m, self.decel, self.slow, self.hold_s = speed, gap_m, decel, slow, hold_s
        self.half_length = car_half_length
        self.state, self.clock_s = "overtaking", 0.0

    def update(self, time_s: float, ego_arc: float, ego_speed: float) -> None:
        ego_front = ego_arc + EGO_HALF_LENGTH_M
        if self.state == "overtaking" and self.arc - self.half_length - ego_front >= self.gap_m:
            self.state = "changing"
        if self.state == "changing":
            self.clock_s += STEP_S
            fraction = min(self.clock_s / self.CHANGE_S, 1.0)
            smooth = fraction * fraction * (3 - 2 * fraction)
            lateral = LANE_WIDTH_M * (1 - smooth)
            self.lateral_rate = (lateral - self.lateral) / STEP_S
            self.lateral = lateral
            self.advance(RESUME_ACCEL, self.cruise)
            if fraction >= 1.0:
                self.state, self.clock_s, self.lateral_rate = "slowing", 0.0, 0.0
        elif self.state == "slowing":
            self.advance(self.decel, self.slow)
            if self.speed <= self.slow:
                self.clock_s += STEP_S
                if self.clock_s >= self.hold_s:
                    self.state = "leaving"
        elif self.state == "leaving":
            self.advance(RESUME_ACCEL, self.cruise)
        else:
            self.advance(RESUME_ACCEL, self.cruise)
        self._place()


class _CrossingCar(_Driven):
    """Drives through the junction without yielding, timed to arrive at the conflict point `timing_s` after the ego
    would (ScenarioRunner's SyncArrival): until it is COMMIT_M from that point its speed is its remaining distance
    over the ego's time to get there (at least CUE_SPEED_MPS), between MIN_SPEED_MPS and MAX_SPEED_MPS and changing
    by at most SYNC_ACCEL per second; from there it keeps its speed through the conflict and speeds up to its
    cruise once past it. A car that slows or stops for it therefore sees it pass; one that keeps going meets it."""

    COMMIT_M = 8.0
    CLEAR_M = 6.0  # past the conflict point by this much it speeds up
    MIN_SPEED_MPS, MAX_SPEED_MPS, SYNC_ACCEL = 3.0, 12.0, 4.0

    def __init__(self, body: Any, path: PathFrame, arc: float, speed: float, conflict_m: float, own_conflict_m: float,
                 timing_s: float) -> None:
        super().__init__(body, "car crossing with the right of way", path, arc, 0.0, speed)
        self.cruise, self.conflict_m, self.own_conflict_m, self.timing_s = speed, conflict_m, own_conflict_m, timing_s
        self.committed = False

    def update(self, time_s: float, ego_arc: float, ego_speed: float) -> None:
        remaining = self.own_conflict_m - self.arc
        if not self.committed and remaining <= self.COMMIT_M:
            self.committed = True
        if self.committed:
            target = self.speed if remaining > -self.CLEAR_M else max(self.speed, self.cruise)
        else:
            due = max(_eta(ego_arc, ego_speed, self.conflict_m) + self.timing_s, 0.1)
            target = min(max(remaining / due, self.MIN_SPEED_MPS), self.MAX_SPEED_MPS)
        self.advance(self.SYNC_ACCEL, target)
        self._place()


class ScenarioManager(BaseManager):
    """Places the scripted actor of the episode's ScenarioSpec after each reset and moves it after each step.

    `configure(spec)` before the env reset (None: no scenario, the manager does nothing). Registered in every
    engine; with no scenario it spawns nothing and draws no random numbers."""

    def __init__(self) -> None:
        super().__init__()
        self.spec: ScenarioSpec | None = None
        self.actors: list[_Actor] = []
        self.route: PathFrame | None = None
        self._time_s = 0.0
        self._ego_arc: float | None = None

    def configure(self, spec: ScenarioSpec | None) -> None:
        self.spec = spec

    def reset(self) -> None:
        super().reset()
        self.actors, self.route, self._time_s, self._ego_arc = [], None, 0.0, None

    def after_reset(self) -> None:
        super().after_reset()
        if self.spec is None:
            return
        agent = next(iter(self.engine.agents.values()))
        graph = self.engine.current_map.road_network.graph
        self.route = PathFrame(route_lanes(graph, list(agent.navigation.checkpoints), 0))
        self._ego_arc = self.route.project(np.asarray(agent.position))
        self.actors = self._place(self.spec, graph, self._ego_arc)
        for actor in self.actors:
            actor.body.msfsu_role = actor.role

    def ego_arc(self) -> float | None:
        return self._ego_arc

    def after_step(self, *args: Any, **kwargs: Any) -> dict:
        if self.spec is None or self.route is None:
            return {}
        agent = next(iter(self.engine.agents.values()))
        self._time_s += STEP_S
        self._ego_arc = self.route.project(np.asarray(agent.position), near_m=self._ego_arc)
        speed = float(np.linalg.norm(agent.velocity))
        for actor in self.actors:
            actor.update(self._time_s, self._ego_arc, speed)
        return {}

    def plan_of(self, body: Any) -> np.ndarray | None:
        """The scripted path ahead of one of this episode's actors (None: not scripted here)."""
        for actor in self.actors:
            if actor.body is body:
                return actor.plan()
        return None

    # ----- placement -----
    def _vehicle(self, name: str, position: np.ndarray, heading: float) -> Any:
        from metadrive.component.vehicle.vehicle_type import vehicle_type

        vehicle_class = vehicle_type[name or "m"] if (name or "m") in vehicle_type else vehicle_type["m"]
        config = {**self.engine.global_config["traffic_vehicle_config"], "enable_reverse": False,
                  "spawn_position_heading": (tuple(float(v) for v in position), float(heading))}
        return self.spawn_object(vehicle_class, vehicle_config=config, random_seed=0)

    def _pedestrian(self, position: np.ndarray, heading: float) -> Any:
        from msfsu_sim.pedestrians import Person

        return self.spawn_object(Person, position=tuple(position), heading_theta=heading, random_seed=0)

    def _place(self, spec: ScenarioSpec, graph: dict, ego_arc: float) -> list[_Actor]:
        route = self.route
        first = route.lanes[0].index
        lanes_each_way = len(graph[first[0]][first[1]])
        left_kerb, right_kerb = kerb_offsets(lanes_each_way)
        conflict = spec.conflict_m
        if spec.kind == PEDESTRIAN_CROSSING:
            start_lateral = right_kerb if spec.side == "right" else left_kerb
            end_lateral = left_kerb if spec.side == "right" else right_kerb
            start, end = route.position(conflict, start_lateral), route.position(conflict, end_lateral)
            enter_m = abs(start_lateral) - (LANE_WIDTH_M / 2 + 0.4)  # to the edge of the ego's lane
            body = self._pedestrian(start, math.atan2(*(end - start)[::-1]))
            return [_Walker(body, f"pedestrian crossing from the {spec.side}", start, end, enter_m,
                            spec.actor_speed_mps, conflict, spec.timing_s)]
        if spec.kind == PEDESTRIAN_BEHIND_PARKED_CAR:
            parked_arc = conflict - 0.6 - PARKED_LENGTH_M / 2  # its front bumper just short of where the person is
            parked = self._vehicle(spec.vehicle, route.position(parked_arc, LANE_WIDTH_M), route.heading(parked_arc))
            parked.set_velocity([1.0, 0.0], 0.0)
            start_lateral = LANE_WIDTH_M + 0.3  # in front of the parked car, hidden behind it from the ego's lane
            start, end = route.position(conflict, start_lateral), route.position(conflict, left_kerb)
            body = self._pedestrian(start, math.atan2(*(end - start)[::-1]))
            walker = _Walker(body, "pedestrian stepping out behind a parked car", start, end,
                             start_lateral - (LANE_WIDTH_M / 2 + 0.4), spec.actor_speed_mps, conflict, spec.timing_s)
            parked_actor = _Parked(parked, "parked car")
            return [walker, parked_actor]
        if spec.kind == LEAD_BRAKING:
            vehicle = self._vehicle(spec.vehicle, route.position(ego_arc), route.heading(ego_arc))
            half = float(vehicle.LENGTH) / 2
            arc = ego_arc + EGO_HALF_LENGTH_M + spec.gap_m + half
            return [_LeadCar(vehicle, route, arc, spec.actor_speed_mps, conflict + half, spec.decel_mps2,
                             spec.hold_s)]
        if spec.kind == CUT_IN:
            vehicle = self._vehicle(spec.vehicle, route.position(ego_arc, LANE_WIDTH_M), route.heading(ego_arc))
            half = float(vehicle.LENGTH) / 2
            # alongside: its rear level with the ego's front
            return [_CuttingCar(vehicle, route, ego_arc + EGO_HALF_LENGTH_M + half, spec.actor_speed_mps, spec.gap_m,
                                spec.decel_mps2, spec.slow_speed_mps, spec.hold_s, half)]
        if spec.kind == CROSSING_TRAFFIC:
            path = PathFrame([graph[a][b][0] for a, b in spec.actor_lanes])
            meet = route.position(conflict)
            own_conflict = path.project(meet)
            start_arc = own_conflict - spec.gap_m
            vehicle = self._vehicle(spec.vehicle, path.position(start_arc), path.heading(start_arc))
            return [_CrossingCar(vehicle, path, start_arc, spec.actor_speed_mps, conflict, own_conflict,
                                 spec.timing_s)]
        return []  # CLEAR_ROAD


class _Parked(_Actor):
    """A car standing still (the parked car of pedestrian_behind_parked_car)."""

    def __init__(self, body: Any, role: str) -> None:
        self.body, self.role = body, role

    def update(self, time_s: float, ego_arc: float, ego_speed: float) -> None:
        self.body.set_velocity([1.0, 0.0], 0.0)

    def plan(self, horizon_s: float = 5.0) -> np.ndarray:
        return np.repeat(np.asarray(self.body.position, np.float64)[None, :2], 2, axis=0)


def crossing_roads(graph: dict, route_roads: list[tuple[str, str]], junction: tuple[str, str]) -> list[list[tuple[str, str]]]:
    """Paths (entry road, junction edge, exit road) of other traffic through the junction edge `junction` of the
    ego's route whose junction lanes cross the ego's: candidates for crossing_traffic."""
    block = block_of(junction[1])
    ego_lane = graph[junction[0]][junction[1]][0]
    ego_points = np.array([ego_lane.position(s, 0.0) for s in np.linspace(0, ego_lane.length, 20)])
    found = []
    for a in sorted(graph):
        for b in sorted(graph[a]):
            if (a, b) == junction or not is_junction_edge(a, b) or (a, b) in route_roads:
                continue
            lane = graph[a][b][0]
            if block not in (block_of(a), block_of(b)):
                continue
            points = np.array([lane.position(s, 0.0) for s in np.linspace(0, lane.length, 20)])
            distances = np.linalg.norm(points[:, None] - ego_points[None], axis=2)
            if distances.min() > 1.0:
                continue  # does not cross the ego's path
            i, j = np.unravel_index(int(np.argmin(distances)), distances.shape)
            theirs = lane.heading_theta_at(lane.length * i / 19)
            ours = ego_lane.heading_theta_at(ego_lane.length * j / 19)
            angle = abs((theirs - ours + math.pi) % (2 * math.pi) - math.pi)
            if not math.radians(45) < angle < math.radians(135):
                continue  # merging or oncoming, not crossing
            entries = [(x, a) for x in sorted(graph) if a in graph[x] and not is_junction_edge(x, a)]
            exits = [(b, y) for y in sorted(graph.get(b, {})) if not is_junction_edge(b, y)]
            if entries and exits:
                found.append([entries[0], (a, b), exits[0]])
    return found
