"""Traffic vehicles that drive from the first step, respawn when they leave the map, and keep clear of the ego.

MetaDrive's default traffic ("trigger" mode) parks the vehicles of each block until the ego car enters
that block from the map's start, in block order. Benchmark and collection routes start anywhere and drive
any direction, so on most of them the traffic never wakes: it stands in its lanes for the whole episode
(the expert then waits behind a parked car until the episode ends `blocked`). Here every vehicle is
driven by MetaDrive's IDM policy from the first step, as CARLA's autopilot traffic is; vehicles that
leave the road network respawn on the map's entry lanes (MetaDrive's "hybrid" mode) away from the ego;
both directions of straight and curved roads get traffic; and nothing spawns inside the episode's clear
zone (msfsu_sim.clearance). MetaDrive's IDM only sees what is on its own lane, so a traffic car drove
into the ego crossing its lane inside a junction (the ego is on a junction lane then): here it also
brakes for the ego car standing in the path its lanes will take it (YieldingIDMPolicy), as a driver at an
uncontrolled junction does, or straight in front of its bumper (a turning car swings off its lane centre).
IDM cars whose lanes cross inside a junction saw nothing of each other and jammed there for good in dense
traffic (the ego then waited behind them until its timeout): a traffic car now also yields to another
traffic car that will reach a point of its planned path first (crossing or turning across it, not one
ahead or behind in its own direction, which IDM follows), the first come being the first served as at an
uncontrolled junction. What still jams (cars already locked into each other) is cleared: a vehicle that
moved less than TOW_MOVED_M in TOW_AFTER_S is towed away and respawned, as a traffic manager clears a stuck
vehicle.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from metadrive.manager.traffic_manager import PGTrafficManager
from metadrive.policy.idm_policy import IDMPolicy

from msfsu_control.path_options import TURN_THRESHOLD_RAD
from msfsu_sim.clearance import DEFAULT_CLEARANCE, ClearZone, SpawnClearance
from msfsu_sim.route import is_junction_edge, route_from_checkpoints, wrap_angle

RESPAWN_TRIES = 20
TOW_AFTER_S = 30.0  # a traffic vehicle that moved less than TOW_MOVED_M in this long is in a jam that will not
TOW_MOVED_M = 3.0  # clear (it creeps at a few cm/s): towed away and respawned
YIELD_LOOK_M = 25.0  # how far along its lanes a traffic car looks for the ego in its way
YIELD_REACH_M = 3.0  # ego centre this close to its path: in its way (two half widths + margin)
EGO_PREDICT_S = np.arange(0.0, 2.01, 0.5)  # where the ego will be, at its current velocity
FRONT_MARGIN_M = 0.5  # beyond the two half widths: the ego is in front of the car's bumper
SAME_DIRECTION_RAD = np.radians(30.0)  # another car heading within this of this one's heading: IDM's business
TURN_SPEED_KMH = 15.0  # traffic through a turn
TURN_SLOWING_M = 15.0  # ... from this far before it


def _is_junction_lane(lane: Any) -> bool:
    """A lane that crosses a junction (msfsu_sim.route's junction edges)."""
    return is_junction_edge(lane.index[0], lane.index[1])


def _is_turn(lane: Any) -> bool:
    """A lane that crosses a junction and turns (msfsu_sim.route's turn threshold)."""
    if not _is_junction_lane(lane):
        return False
    change = wrap_angle(lane.heading_theta_at(lane.length) - lane.heading_theta_at(0.0))
    return abs(change) > TURN_THRESHOLD_RAD


class YieldingIDMPolicy(IDMPolicy):
    """MetaDrive's IDM, which also brakes for the ego car where it stands in this car's planned path, or will
    within EGO_PREDICT_S at its current velocity (a car nosing into a junction is yielded to before it is
    in the lane, as a driver does who sees it come); and which takes turns at TURN_SPEED_KMH (at its 30 km/h
    cruise MetaDrive's lane PID swung turning cars wide into the oncoming lanes, onto cars waiting there)."""

    def acceleration(self, front_obj: Any, dist_to_front: float) -> float:
        cruise = self.target_speed
        if self._turning_soon():
            self.target_speed = min(cruise, TURN_SPEED_KMH)
        try:
            return super().acceleration(front_obj, dist_to_front)
        finally:
            self.target_speed = cruise

    def _turning_soon(self) -> bool:
        """On a turn through a junction, or within TURN_SLOWING_M of the one its route takes next."""
        vehicle = self.control_object
        lane = vehicle.lane
        if _is_turn(lane):
            return True
        left = lane.length - lane.local_coordinates(np.asarray(vehicle.position))[0]
        if left > TURN_SLOWING_M:
            return False
        following = _next_lane(lane, self.engine.current_map.road_network.graph, list(vehicle.navigation.checkpoints))
        return following is not None and _is_turn(following)

    def act(self, *args: Any, **kwargs: Any) -> list[float]:
        action = super().act(*args, **kwargs)
        vehicle = self.control_object
        ego = next(iter(self.engine.agents.values()))
        position = np.asarray(vehicle.position, np.float64)
        reach = YIELD_LOOK_M + vehicle.LENGTH
        graph = self.engine.current_map.road_network.graph
        candidates = [ego] if np.linalg.norm(np.asarray(ego.position) - position) <= reach else []
        others, positions = self.engine.traffic_manager.positions()
        near = [others[i] for i in np.flatnonzero(np.linalg.norm(positions - position, axis=1) <= reach)
                if others[i] is not vehicle] if len(others) else []
        if near:  # between junctions lanes do not cross: IDM handles its own lane
            at_junction = _at_junction(vehicle, graph)
            candidates += [other for other in near if at_junction or _is_junction_lane(other.lane)]
        if not candidates:
            return action
        path = planned_path(vehicle, graph, YIELD_LOOK_M, step_m=1.0)
        yield_to = []  # (gap, other)
        for other in candidates:
            found = ((_gap_along_path(vehicle, path, ego), front_gap(vehicle, ego)) if other is ego
                     else (_first_come_gap(vehicle, path, other),))
            gaps = [g for g in found if g is not None]
            if gaps:
                yield_to.append((min(gaps), other))
        if yield_to:
            gap, other = min(yield_to, key=lambda item: item[0])
            action[1] = min(action[1], self.acceleration(other, max(gap, 0.1)))
        return action


def _at_junction(vehicle: Any, graph: dict) -> bool:
    """In a junction, or within YIELD_LOOK_M of entering the one its route takes next (between junctions the
    lanes do not cross: an oncoming car extrapolated along a curve is no conflict)."""
    if _is_junction_lane(vehicle.lane):
        return True
    lane = vehicle.lane
    left = lane.length - lane.local_coordinates(np.asarray(vehicle.position))[0]
    if left > YIELD_LOOK_M:
        return False
    following = _next_lane(lane, graph, list(vehicle.navigation.checkpoints))
    return following is not None and _is_junction_lane(following)


def _path_hits(path: np.ndarray, other: Any) -> tuple[int, float] | None:
    """(index of the first point of `path` that `other` is at, or will be at within EGO_PREDICT_S at its
    current velocity; the earliest such time), or None."""
    if not len(path):
        return None
    ahead = np.asarray(other.position, np.float64) + EGO_PREDICT_S[:, None] * np.asarray(other.velocity, np.float64)
    distances = np.linalg.norm(path[None, :, :] - ahead[:, None, :], axis=2)  # (T, N)
    inside = np.flatnonzero(distances.min(axis=0) < YIELD_REACH_M)
    if not len(inside):
        return None
    return int(inside[0]), float(EGO_PREDICT_S[np.argmax(distances[:, inside[0]] < YIELD_REACH_M)])


def _gap_along_path(vehicle: Any, path: np.ndarray, other: Any) -> float | None:
    """Bumper gap to where `other` is, or will be within EGO_PREDICT_S, on `path` (1 m steps)."""
    hit = _path_hits(path, other)
    return None if hit is None else (hit[0] + 1) * 1.0 - vehicle.LENGTH / 2 - other.LENGTH / 2


def _first_come_gap(vehicle: Any, path: np.ndarray, other: Any) -> float | None:
    """The gap to yield at if traffic car `other` crosses `path` (1 m steps) and gets to the meeting point
    first (ties: the car with the smaller (x, y) goes first, a rule both see alike: not the vehicle ids, which
    are random per process); None if it drives this car's way (IDM follows it) or comes later."""
    heading = np.asarray(vehicle.heading, np.float64)
    if float(heading @ np.asarray(other.heading, np.float64)) > np.cos(SAME_DIRECTION_RAD):
        return None
    hit = _path_hits(path, other)
    if hit is None:
        return None
    index, other_s = hit
    distance = (index + 1) * 1.0
    own_s = distance / max(float(np.linalg.norm(vehicle.velocity)), 1.0)
    if other_s > own_s or (other_s == own_s and tuple(other.position) > tuple(vehicle.position)):
        return None
    return distance - vehicle.LENGTH / 2 - other.LENGTH / 2


def front_gap(vehicle: Any, ego: Any) -> float | None:
    """Bumper gap to the ego if it is straight in front of `vehicle` (along its heading, within YIELD_LOOK_M, its
    body overlapping the car's width): a car that swings wide in a turn, or drives off its lane centre, is off
    the path its lanes describe but still must not drive into what is in front of its bumper."""
    heading = np.asarray(vehicle.heading, np.float64)  # unit vector
    offset = np.asarray(ego.position, np.float64) - np.asarray(vehicle.position, np.float64)
    along = float(offset @ heading)
    across = abs(float(offset[0] * heading[1] - offset[1] * heading[0]))
    if along <= 0.0 or along > YIELD_LOOK_M or across > vehicle.WIDTH / 2 + ego.WIDTH / 2 + FRONT_MARGIN_M:
        return None
    return along - vehicle.LENGTH / 2 - ego.LENGTH / 2


def ego_clear_zone(engine: Any, clearance: SpawnClearance) -> ClearZone:
    """The clear zone around the ego car as it stands after reset, along the route it will drive."""
    agent = next(iter(engine.agents.values()))
    graph = engine.current_map.road_network.graph
    route = route_from_checkpoints(graph, agent.navigation.checkpoints, agent.lane_index[2])
    position = np.asarray(agent.position, np.float64)
    start = int(np.argmin(np.linalg.norm(route.poses[:, :2] - position, axis=1)))
    return ClearZone(tuple(position), route.poses[start:, :2], clearance)


class TrafficManager(PGTrafficManager):
    """PGTrafficManager with every vehicle active from the start, respawn, and the spawn clearance."""

    def __init__(self) -> None:
        super().__init__()
        self.clearance = DEFAULT_CLEARANCE
        self.dropped_at_reset = 0  # vehicles removed from the clear zone at the last reset
        self.towed = 0  # vehicles towed away this episode (standing TOW_AFTER_S)
        self.named = 0  # traffic cars named this episode (_name)
        self._anchor: dict[str, tuple[np.ndarray, float]] = {}  # per vehicle: where it was and how long ago (s)
        self._zone: ClearZone | None = None
        self._positions_step: int | None = None
        self._positions: tuple[list, np.ndarray] = ([], np.zeros((0, 2)))

    def configure(self, clearance: SpawnClearance) -> None:
        self.clearance = clearance

    def _name(self, vehicle: Any) -> None:
        """Number the episode's traffic cars in the order they came (environment.actor_name)."""
        vehicle.msfsu_role = f"traffic car {self.named}"
        self.named += 1

    def positions(self) -> tuple[list, np.ndarray]:
        """The traffic vehicles and their (N, 2) positions at this step (computed once per step for all)."""
        step = self.engine.episode_step
        if self._positions_step != step:
            vehicles = list(self._traffic_vehicles)
            self._positions = (vehicles, np.array([v.position for v in vehicles], np.float64).reshape(-1, 2))
            self._positions_step = step
        return self._positions

    def after_reset(self) -> None:
        super().after_reset()
        for block in self.block_triggered_vehicles:  # wake every block's vehicles now
            self._traffic_vehicles += list(self.get_objects(block.vehicles).values())
        self.block_triggered_vehicles = []
        self.named = 0
        for vehicle in self._traffic_vehicles:
            self.add_policy(vehicle.id, YieldingIDMPolicy, vehicle, self.generate_seed())
            self._name(vehicle)
        self._zone = ego_clear_zone(self.engine, self.clearance)
        self._positions_step = None
        self.towed = 0
        self._anchor = {}
        too_close = [v for v in self._traffic_vehicles if self._zone.blocks(v.position, v.LENGTH / 2)]
        self._remove(too_close)
        self.dropped_at_reset = len(too_close)

    def after_step(self, *args: Any, **kwargs: Any) -> dict:
        step_s = self.engine.global_config["physics_world_step_size"] * self.engine.global_config["decision_repeat"]
        left = []
        for vehicle in self._traffic_vehicles:
            vehicle.after_step()
            position = np.asarray(vehicle.position, np.float64)
            anchor, since_s = self._anchor.get(vehicle.id, (position, 0.0))
            moved = np.linalg.norm(position - anchor) > TOW_MOVED_M
            self._anchor[vehicle.id] = (position, 0.0) if moved else (anchor, since_s + step_s)
            if not vehicle.on_lane:
                left.append(vehicle)
            elif not moved and since_s + step_s >= TOW_AFTER_S:
                left.append(vehicle)  # MetaDrive's traffic jams for good where IDM cars meet inside a junction
                self.towed += 1
        types = [type(vehicle) for vehicle in left]
        self._remove(left)
        for vehicle_type in types:
            self._respawn(vehicle_type)
        return {}

    def _remove(self, vehicles: list) -> None:
        if vehicles:
            self.clear_objects([vehicle.id for vehicle in vehicles])
            removed = {vehicle.id for vehicle in vehicles}
            for vehicle_id in removed:
                self._anchor.pop(vehicle_id, None)
            self._traffic_vehicles = [v for v in self._traffic_vehicles if v.id not in removed]

    def _respawn(self, vehicle_type: type) -> None:
        """A vehicle on a random entry lane, at least VEHICLE_GAP from every vehicle and clear of the ego."""
        if not self.respawn_lanes:
            return
        agent = next(iter(self.engine.agents.values()))
        occupied = [np.asarray(v.position) for v in self._traffic_vehicles] + [np.asarray(agent.position)]
        for _ in range(RESPAWN_TRIES):
            lane = self.respawn_lanes[self.np_random.randint(0, len(self.respawn_lanes))]
            longitude = self.np_random.rand() * lane.length / 2
            position = np.asarray(lane.position(longitude, 0.0))
            if np.linalg.norm(position - occupied[-1]) < self.clearance.radius_m:
                continue
            if any(np.linalg.norm(position - other) < self.VEHICLE_GAP for other in occupied[:-1]):
                continue
            config = {"spawn_lane_index": lane.index, "spawn_longitude": longitude, "enable_reverse": False,
                      **self.engine.global_config["traffic_vehicle_config"]}
            vehicle = self.spawn_object(vehicle_type, vehicle_config=config)
            self.add_policy(vehicle.id, YieldingIDMPolicy, vehicle, self.generate_seed())
            self._traffic_vehicles.append(vehicle)
            self._name(vehicle)
            return


def planned_path(vehicle: Any, graph: dict, length_m: float, step_m: float = 2.0) -> np.ndarray:
    """(N, 2) points every `step_m` along the lanes the vehicle will drive (its lane, then the lanes of its
    navigation's next roads, keeping to the lane that continues its own), from its position on."""
    lane = vehicle.lane
    checkpoints = list(vehicle.navigation.checkpoints)
    s = float(lane.local_coordinates(np.asarray(vehicle.position))[0])
    points = []
    while len(points) * step_m < length_m:
        if s > lane.length:
            following = _next_lane(lane, graph, checkpoints)
            if following is None:
                break
            s -= lane.length
            lane = following
        points.append(lane.position(s, 0.0))
        s += step_m
    return np.asarray(points, np.float64).reshape(-1, 2)


def _next_lane(lane: Any, graph: dict, checkpoints: list[str]) -> Any | None:
    """The lane after `lane`: on the road its route takes next (else any road on), the one joining it."""
    end = lane.index[1]
    roads = graph.get(end, {})
    if not roads:
        return None
    position = checkpoints.index(end) if end in checkpoints else -1
    ahead = checkpoints[position + 1] if 0 <= position < len(checkpoints) - 1 else None
    lanes = roads.get(ahead) or next(iter(roads.values()))
    joined = [candidate for candidate in lanes if lane.is_previous_lane_of(candidate)]
    return (joined or [min(lanes, key=lambda c: np.linalg.norm(np.asarray(c.position(0.0, 0.0))
                                                               - np.asarray(lane.position(lane.length, 0.0))))])[0]
