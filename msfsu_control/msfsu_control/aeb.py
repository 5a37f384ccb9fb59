"""Autonomous emergency braking on the network's own scene understanding (ROS-free, numpy only).

Each frame: the network's segmentation (class ids of its crop of the camera image) and the depth of the same frame
at its pixels give the 3-D points of those it calls vehicle_or_pedestrian (msfsu_common.camera_geometry); those inside
the corridor the car will sweep (its width plus a margin, bent by the steer the network asked for, as far as the car
goes in `horizon_s`) and above the road (a pixel of a vehicle or a person, not a mislabelled patch of asphalt) are
obstacles. The nearest one's gap to the front bumper, and how fast that gap closes (a line through the last gaps, or
the car's own speed while there are too few), give the time to collision. The decision:

- brake (target speed 0: the control's PID brakes fully below its stop speed): the gap is within `stop_gap_m`, or
  within the distance the car needs to stop at `brake_decel` after `reaction_s`, or the time to collision is below
  `brake_ttc_s`;
- cap the target speed: the time to collision is below `cap_ttc_s` and the network asks for more than the speed from
  which the car stops `stop_gap_m` short of the obstacle at `cap_decel`, the obstacle's own speed away from the car
  counted in (Gipps' safe speed): the cap;
- none otherwise.

Crossing (`predict_crossing`, on by default; it needs the car's pose from its odometry): the obstacles beside the
corridor, up to `watch_m` beyond its edge, are clusters (connected regions of the segmentation), each followed over
frames in the world frame (so the car's own turning is not taken for their motion) by its median point; a track not
seen for `track_lost_s` ends (its next sighting starts a new one, which has no speed until followed for a few frames),
so a patch the segmentation shows in scattered frames moves nothing. One that moves towards the car's path
at `min_crossing_speed` or more, and whose time in the corridor (from entering it to leaving it on the other side)
overlaps the time the car takes to reach and pass it (at the speed asked for, or driven, whichever is higher, less the
obstacle's own speed along the path: a car in the next lane coming the other way is passed before it could be in the
corridor, one ahead going the same way is never reached), caps the target speed to the speed at which the car arrives
`stop_gap_m` short of the nearest point it crosses the corridor at after it has left: 0 (the PID brakes) while that is
not possible. A pedestrian 3 m beside the path walking into it is seen before it is in the corridor, not once it is.

Hysteresis: a brake is held until the corridor has been free of any reason to brake for `release_s`; a cap likewise
lasts `release_s` after its last reason, so neither chatters. An obstacle must show at least `min_pixels` pixels in
the corridor.

The depth is the camera's, read at the centre of each segmentation pixel (`depth_at_crop_pixels` of
msfsu_common.camera_geometry: the perception node publishes it beside the segmentation, so the camera's full depth
image goes to one process only).

Fail-safe rule, for a frame the AEB cannot judge (no segmentation or depth of the frame, depth samples not of the
segmentation's size, more than `max_invalid_depth_fraction` of the depth samples NaN or not positive): the frame is a
counted drop; the last decision stands for `hold_on_loss_s` (a brake is not let go because one frame was lost), after
which the network's action passes unchanged (an AEB that cannot see must not stop the car at random, where the car
behind would hit it). Single NaN pixels are left out of the points.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import cv2
import numpy as np

from msfsu_common.camera_geometry import CameraView
from msfsu_common.semantic_classes import SemanticClass
from msfsu_common.settings import setting

NONE, CAP, BRAKE = "none", "cap", "brake"
DECISIONS = (NONE, CAP, BRAKE)
DROP_REASONS = ("no_segmentation", "no_depth", "bad_segmentation", "invalid_depth")


@dataclass(frozen=True)
class AebConfig:
    """What the AEB judges with (every field a live parameter of the `aeb` node)."""

    half_width_m: float = setting(1.0, "half the car's width, m", 0.3, 3.0)
    margin_m: float = setting(0.4, "corridor margin beyond the car's width on each side, m", 0.0, 3.0)
    front_m: float = setting(2.3, "from the car's centre to its front bumper, m", 0.0, 10.0)
    wheelbase_m: float = setting(2.5, "wheelbase: bends the corridor with the steer, m", 0.5, 10.0)
    max_steer_deg: float = setting(40.0, "wheel angle at steer 1, degrees", 1.0, 89.0)
    horizon_s: float = setting(3.0, "the corridor reaches as far as the car goes in this long, s", 0.1, 20.0)
    min_range_m: float = setting(6.0, "... and at least this far beyond the bumper, m", 0.0, 100.0)
    max_range_m: float = setting(40.0, "never farther than this, m", 1.0, 200.0)
    min_height_m: float = setting(0.3, "obstacle points lie above this height over the road, m", -1.0, 5.0)
    max_height_m: float = setting(3.0, "... and below this, m", 0.0, 10.0)
    min_pixels: int = setting(4, "segmentation pixels of obstacle in the corridor that count as one", 1, 10000)
    stop_gap_m: float = setting(2.0, "brake when the gap to the obstacle is within this, m", 0.0, 50.0)
    brake_ttc_s: float = setting(1.2, "brake when the time to collision is below this, s", 0.0, 20.0)
    cap_ttc_s: float = setting(3.0, "cap the target speed when the time to collision is below this, s", 0.0, 30.0)
    brake_decel: float = setting(6.0, "deceleration the brake gives, m/s^2 (the stopping distance)", 0.5, 30.0)
    reaction_s: float = setting(0.2, "delay before the brake acts, s", 0.0, 5.0)
    cap_decel: float = setting(3.0, "deceleration the speed cap plans with, m/s^2", 0.5, 30.0)
    release_s: float = setting(1.0, "a brake or cap is let go after the corridor is free of its reason this long, s",
                               0.0, 30.0)
    closing_window_s: float = setting(0.5, "closing speed and crossing tracks: a line through this long, s", 0.1, 5.0)
    max_invalid_depth_fraction: float = setting(0.5, "a frame with more invalid depth samples is a drop", 0.0, 1.0)
    hold_on_loss_s: float = setting(0.5, "after a drop the last decision stands this long, then the action passes", 0.0,
                                    10.0)
    predict_crossing: bool = setting(True, "also act on obstacles beside the corridor moving into it (tracked)")
    watch_m: float = setting(4.0, "crossing: obstacles are followed this far beyond the corridor's edge, m", 0.0, 20.0)
    min_crossing_speed: float = setting(0.5, "crossing: slower towards the path than this is not crossing, m/s", 0.05,
                                        10.0)
    track_gate_m: float = setting(1.5, "crossing: a cluster this close to a track's last point continues it, m", 0.1,
                                  10.0)
    track_lost_s: float = setting(0.25, "crossing: a track not seen this long ends, s", 0.0, 5.0)
    rear_m: float = setting(2.2, "from the car's centre to its rear bumper, m (the car has passed)", 0.0, 10.0)


@dataclass(frozen=True)
class Obstacle:
    """The nearest obstacle in the corridor of one frame."""

    gap_m: float  # from the front bumper, along the corridor
    lateral_m: float  # from the corridor's centre line
    pixels: int  # segmentation pixels of obstacle inside the corridor


@dataclass(frozen=True)
class Cluster:
    """One connected region of obstacle pixels beside or in the corridor: its median point in the car's frame."""

    forward_m: float
    right_m: float
    pixels: int


@dataclass(frozen=True)
class Crossing:
    """An obstacle beside the corridor moving into the car's path in time to meet the car."""

    gap_m: float  # along the path, from the front bumper
    lateral_m: float  # from the path's centre line now
    toward_mps: float  # how fast it comes towards the centre line
    along_mps: float  # how fast it moves along the path (away from the car: positive)
    enter_s: float  # when it enters the corridor, from now
    leave_s: float  # when it has crossed it
    pixels: int


@dataclass(frozen=True)
class Decision:
    """What the AEB does with one frame's action."""

    kind: str  # NONE, CAP or BRAKE
    target_speed: float  # the action's target speed after the AEB
    reason: str  # why (the rule that holds), "" for NONE
    gap_m: float  # to the nearest obstacle in the corridor (inf: none)
    ttc_s: float  # time to collision (inf: none or not closing)
    pixels: int
    dropped: str = ""  # DROP_REASONS when the frame could not be judged


def corridor_arc(forward: np.ndarray, right: np.ndarray, curvature: float) -> tuple[np.ndarray, np.ndarray]:
    """Vehicle-frame points -> (arc length along the path the car drives at `curvature` (1/m, positive turning
    right), signed distance from that path). The path starts at the car's centre heading forward."""
    if abs(curvature) < 1e-6:
        return forward, right
    radius = 1.0 / curvature  # the turn's centre is at (0, radius): right of the car for a right turn
    angle = np.arctan2(forward, np.abs(radius) - np.sign(radius) * right)
    arc = np.abs(radius) * np.where(angle < 0, angle + 2 * np.pi, angle)
    lateral = np.sign(radius) * (np.abs(radius) - np.hypot(forward, right - radius))
    return arc, lateral


def obstacle_points(segmentation: np.ndarray, depth: np.ndarray,
                    camera: CameraView) -> tuple[np.ndarray, ...] | None:
    """The pixels the segmentation calls vehicle_or_pedestrian with a valid depth: (row, column) in the segmentation
    and (forward, right, up) in the car's frame, metres; None when there are none.

    `segmentation` (h, w) class ids of the camera's crop (camera.crop_top_fraction); `depth` (h, w) metres along the
    optical axis at each of its pixels (msfsu_common.camera_geometry.depth_at_crop_pixels of the camera's depth
    image); `camera` the full camera image's size, mount and lens (camera.width x camera.height)."""
    mask = segmentation == SemanticClass.VEHICLE_OR_PEDESTRIAN
    if not mask.any():
        return None
    rows, columns = segmentation.shape
    column, row = camera.crop_pixel_centres(rows, columns)
    seg_row, seg_column = np.nonzero(mask)
    column, row, distance = column[mask], row[mask], depth[mask]
    valid = np.isfinite(distance) & (distance > 0)
    return (seg_row[valid], seg_column[valid], *camera.back_project(column[valid], row[valid], distance[valid]))


def curvature_of(steer: float, config: AebConfig) -> float:
    """The path's curvature (1/m, positive right) at the steer the network asked for."""
    return math.tan(math.radians(config.max_steer_deg) * max(-1.0, min(1.0, steer))) / config.wheelbase_m


def corridor_reach(speed: float, config: AebConfig) -> float:
    """How far along the path from the car's centre the corridor reaches, m."""
    return min(config.front_m + max(config.min_range_m, speed * config.horizon_s), config.front_m + config.max_range_m)


def near_path(points: tuple[np.ndarray, ...], steer: float, speed: float, config: AebConfig,
              half_width_m: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """obstacle_points -> (arc, lateral) along the path the steer bends, and which of them lie within `half_width_m`
    of it, past the car's centre, within the corridor's reach and above the road (min_height_m to max_height_m)."""
    _, _, forward, right, up = points
    arc, lateral = corridor_arc(forward, right, curvature_of(steer, config))
    return arc, lateral, ((np.abs(lateral) <= half_width_m) & (arc > 0.5) & (arc <= corridor_reach(speed, config))
                          & (up >= config.min_height_m) & (up <= config.max_height_m))


def find_obstacle(segmentation: np.ndarray, depth: np.ndarray, camera: CameraView, steer: float, speed: float,
                  config: AebConfig, points: tuple[np.ndarray, ...] | None = None) -> Obstacle | None:
    """The nearest obstacle in the corridor of this frame, None if the corridor is clear (`points`: this frame's
    obstacle_points when already computed)."""
    points = obstacle_points(segmentation, depth, camera) if points is None else points
    if points is None:
        return None
    arc, lateral, inside = near_path(points, steer, speed, config, config.half_width_m + config.margin_m)
    if np.count_nonzero(inside) < config.min_pixels:
        return None
    gaps = arc[inside] - config.front_m
    nearest = int(np.argmin(gaps))
    return Obstacle(float(gaps[nearest]), float(lateral[inside][nearest]), int(np.count_nonzero(inside)))


def find_clusters(segmentation: np.ndarray, points: tuple[np.ndarray, ...] | None, steer: float, speed: float,
                  config: AebConfig) -> list[Cluster]:
    """The connected regions of obstacle pixels with at least `min_pixels` points above the road within `watch_m` of
    the corridor's edge and its reach: each one's median point."""
    if points is None:
        return []
    seg_row, seg_column, forward, right, _ = points
    _, _, near = near_path(points, steer, speed, config, config.half_width_m + config.margin_m + config.watch_m)
    if np.count_nonzero(near) < config.min_pixels:
        return []
    mask = (segmentation == SemanticClass.VEHICLE_OR_PEDESTRIAN).astype(np.uint8)
    _, labels = cv2.connectedComponents(mask, connectivity=8)
    component = labels[seg_row[near], seg_column[near]]
    forward, right = forward[near], right[near]
    clusters = []
    for label in np.unique(component):
        members = component == label
        if np.count_nonzero(members) >= config.min_pixels:
            clusters.append(Cluster(float(np.median(forward[members])), float(np.median(right[members])),
                                    int(np.count_nonzero(members))))
    return clusters


def to_world(pose: tuple[float, float, float], forward: float, right: float) -> tuple[float, float]:
    """A point in the car's frame (forward, right) -> the odometry's frame (x, y; yaw counter-clockwise from x)."""
    x, y, yaw = pose
    cos, sin = math.cos(yaw), math.sin(yaw)
    return x + forward * cos + right * sin, y + forward * sin - right * cos


def to_car(yaw: float, vx: float, vy: float) -> tuple[float, float]:
    """A velocity in the odometry's frame -> (forward, right) in the car's frame."""
    cos, sin = math.cos(yaw), math.sin(yaw)
    return vx * cos + vy * sin, vx * sin - vy * cos


class Tracks:
    """Clusters followed over frames in the world frame: each new cluster continues the nearest track whose last point
    is within `gate_m` (the largest clusters choose first) or starts one; a track not seen for `lost_s` ends."""

    def __init__(self) -> None:
        self._tracks: list[deque[tuple[float, float, float]]] = []  # (time, x, y), oldest first

    def update(self, time_s: float, points: list[tuple[float, float]], gate_m: float, window_s: float,
               lost_s: float) -> list[tuple[float, float] | None]:
        """The world points of this frame's clusters (largest first) -> each one's velocity (vx, vy) in m/s, a line
        through its points of the last `window_s`; None while they span too little time (fewer than 3 frames or
        0.2 s)."""
        self._tracks = [track for track in self._tracks if time_s - track[-1][0] <= lost_s + 1e-9]
        free = list(range(len(self._tracks)))
        velocities: list[tuple[float, float] | None] = []
        for x, y in points:
            distances = [math.dist((x, y), self._tracks[i][-1][1:]) for i in free]
            if distances and min(distances) <= gate_m:
                track = self._tracks[free.pop(int(np.argmin(distances)))]
            else:
                track = deque()
                self._tracks.append(track)
            track.append((time_s, x, y))
            while time_s - track[0][0] > window_s:
                track.popleft()
            velocities.append(self.velocity(track))
        return velocities

    @staticmethod
    def velocity(track: deque[tuple[float, float, float]]) -> tuple[float, float] | None:
        if len(track) < 3 or track[-1][0] - track[0][0] < 0.2:
            return None
        times, xs, ys = np.array(track).T
        times = times - times.mean()  # the least-squares slope of a line through the points
        return float(times @ xs / (times @ times)), float(times @ ys / (times @ times))


def crossing(cluster: Cluster, velocity: tuple[float, float], steer: float, plan_speed: float,
             config: AebConfig) -> Crossing | None:
    """`cluster` moving at `velocity` (forward, right, m/s: its speed over the ground in the car's axes) -> a
    Crossing when it is beside the corridor, comes towards the path at min_crossing_speed or more and is in the
    corridor at some time the car, at `plan_speed`, is between reaching it with its front and passing it with its rear
    (the obstacle moving along the path meanwhile); None otherwise."""
    curvature = curvature_of(steer, config)
    dt = 0.1
    arcs, laterals = corridor_arc(np.array([cluster.forward_m, cluster.forward_m + velocity[0] * dt]),
                                  np.array([cluster.right_m, cluster.right_m + velocity[1] * dt]), curvature)
    lateral, gap = float(laterals[0]), float(arcs[0]) - config.front_m
    toward = -math.copysign(1.0, lateral) * float(laterals[1] - laterals[0]) / dt
    along = float(arcs[1] - arcs[0]) / dt
    half = config.half_width_m + config.margin_m
    if abs(lateral) <= half or toward < config.min_crossing_speed or gap <= 0:
        return None
    enter, leave = (abs(lateral) - half) / toward, (abs(lateral) + half) / toward
    if enter > config.horizon_s:
        return None
    if plan_speed > 0.05:
        closing = plan_speed - along  # how fast the car comes up to it along the path
        if closing <= 0.05:
            return None  # going the car's way at least as fast: never reached
        front, rear = gap / closing, (gap + config.front_m + config.rear_m) / closing
        if not (enter < rear and leave > front):
            return None
    return Crossing(gap, lateral, toward, along, enter, leave, cluster.pixels)


def invalid_depth_fraction(depth: np.ndarray) -> float:
    """The share of the depth samples (one per segmentation pixel) that are NaN, infinite or not positive."""
    if depth.size == 0:
        return 1.0
    return 1.0 - float(np.count_nonzero(np.isfinite(depth) & (depth > 0))) / depth.size


class EmergencyBrake:
    """The AEB of one car: `step` once per frame, in frame order."""

    def __init__(self, config: AebConfig = AebConfig()) -> None:
        self.config = config
        self.state = NONE
        self.reason = ""
        self._free_since: float | None = None  # when the state's reason last went away
        self._gaps: deque[tuple[float, float]] = deque()  # (time, gap) of the nearest obstacle, recent
        self._last_judged: float | None = None  # time of the last frame judged
        self._cap = math.inf
        self._tracks = Tracks()
        self.drops = dict.fromkeys(DROP_REASONS, 0)
        self.decisions = dict.fromkeys(DECISIONS, 0)

    def reset(self) -> None:
        self.__init__(self.config)

    def closing_speed(self, speed: float) -> float:
        """How fast the gap to the nearest obstacle closes (m/s): the slope of a line through its recent gaps, or the
        car's own speed (an obstacle standing still) while they span too little time."""
        if len(self._gaps) < 3 or self._gaps[-1][0] - self._gaps[0][0] < 0.2:
            return speed
        times, gaps = np.array(self._gaps).T
        return float(-np.polyfit(times - times[-1], gaps, 1)[0])

    def _wanted(self, obstacle: Obstacle | None, speed: float, closing: float,
                target_speed: float) -> tuple[str, str, float, float]:
        """(decision, reason, time to collision, cap) this frame asks for, before hysteresis; a cap the network's
        target speed is already below is none."""
        config = self.config
        if obstacle is None:
            return NONE, "", math.inf, math.inf
        gap = obstacle.gap_m
        ttc = gap / closing if closing > 0.05 else math.inf
        stopping = speed * config.reaction_s + speed * speed / (2 * config.brake_decel)
        if gap <= config.stop_gap_m:
            return BRAKE, "obstacle within the stop gap", ttc, 0.0
        if gap <= stopping + config.stop_gap_m and closing > 0.05:
            return BRAKE, "within the stopping distance", ttc, 0.0
        if ttc < config.brake_ttc_s:
            return BRAKE, "time to collision", ttc, 0.0
        if ttc < config.cap_ttc_s:
            away = max(speed - closing, 0.0)  # the obstacle's own speed along the corridor
            cap = math.sqrt(away * away + 2 * config.cap_decel * max(gap - config.stop_gap_m, 0.0))
            if cap < target_speed:
                return CAP, "time to collision", ttc, cap
        return NONE, "", ttc, math.inf

    def step(self, time_s: float, target_speed: float, steer: float, speed: float, segmentation: np.ndarray | None,
             depth: np.ndarray | None, camera: CameraView | None,
             pose: tuple[float, float, float] | None = None) -> Decision:
        """One frame: the network's target speed and steer, the car's speed, the frame's segmentation and the depth at
        its pixels (depth_at_crop_pixels; None: not there), the camera they came from and the car's pose (x, y, yaw
        counter-clockwise; None: unknown, no crossing is predicted) -> the decision and the target speed to drive."""
        config = self.config
        dropped = ""
        if segmentation is None:
            dropped = "no_segmentation"
        elif depth is None or camera is None:
            dropped = "no_depth"
        elif segmentation.ndim != 2 or depth.shape != segmentation.shape:
            dropped = "bad_segmentation"
        elif invalid_depth_fraction(depth) > config.max_invalid_depth_fraction:
            dropped = "invalid_depth"
        if dropped:
            self.drops[dropped] += 1
            held = self._last_judged is not None and time_s - self._last_judged <= config.hold_on_loss_s
            kind = self.state if held else NONE
            target = self._apply(kind, target_speed)
            self.decisions[kind] += 1
            return Decision(kind, target, f"{self.reason} (held: {dropped})" if kind != NONE else "",
                            math.inf, math.inf, 0, dropped)
        points = obstacle_points(segmentation, depth, camera)
        obstacle = find_obstacle(segmentation, depth, camera, steer, speed, config, points)
        if obstacle is None:
            self._gaps.clear()
        else:
            self._gaps.append((time_s, obstacle.gap_m))
            while self._gaps and time_s - self._gaps[0][0] > config.closing_window_s:
                self._gaps.popleft()
        wanted, reason, ttc, cap = self._wanted(obstacle, speed, self.closing_speed(speed), target_speed)
        gap, pixels = (obstacle.gap_m, obstacle.pixels) if obstacle else (math.inf, 0)
        if config.predict_crossing and pose is not None and wanted != BRAKE:
            crosser = self._crossing(time_s, segmentation, points, steer, speed, target_speed, pose)
            if crosser is not None:
                # where it crosses the corridor nearest the car, while it is in it
                nearest = crosser.gap_m + min(crosser.along_mps * crosser.enter_s, crosser.along_mps * crosser.leave_s)
                crossing_cap = max(nearest - config.stop_gap_m, 0.0) / crosser.leave_s
                if crossing_cap < min(cap, target_speed):
                    wanted, reason, cap = CAP, "crossing into the corridor", crossing_cap
                    gap, pixels = crosser.gap_m, crosser.pixels
                    ttc = crosser.gap_m / speed if speed > 0.05 else math.inf
        self._update(time_s, wanted, reason, cap)
        self._last_judged = time_s
        self.decisions[self.state] += 1
        return Decision(self.state, self._apply(self.state, target_speed), self.reason if self.state != NONE else "",
                        gap, ttc, pixels)

    def _crossing(self, time_s: float, segmentation: np.ndarray, points: tuple[np.ndarray, ...] | None, steer: float,
                  speed: float, target_speed: float, pose: tuple[float, float, float]) -> Crossing | None:
        """This frame's clusters, followed; the crossing the car meets first (None: none)."""
        config = self.config
        clusters = sorted(find_clusters(segmentation, points, steer, speed, config), key=lambda c: -c.pixels)
        velocities = self._tracks.update(time_s, [to_world(pose, c.forward_m, c.right_m) for c in clusters],
                                         config.track_gate_m, config.closing_window_s, config.track_lost_s)
        found = [crossing(cluster, to_car(pose[2], *velocity), steer, max(speed, target_speed), config)
                 for cluster, velocity in zip(clusters, velocities) if velocity is not None]
        found = [c for c in found if c is not None]
        return min(found, key=lambda c: c.gap_m) if found else None

    def _update(self, time_s: float, wanted: str, reason: str, cap: float) -> None:
        """Hysteresis: a stronger decision takes over at once; a weaker one only after the current one's reason has
        been gone for release_s."""
        rank = DECISIONS.index
        if rank(wanted) >= rank(self.state):
            if wanted != NONE:
                self.state, self.reason, self._free_since = wanted, reason, None
                self._cap = cap if wanted == CAP else 0.0
            return
        if self._free_since is None:
            self._free_since = time_s
        if time_s - self._free_since >= self.config.release_s - 1e-9:
            self.state, self.reason, self._free_since = wanted, reason if wanted != NONE else "", None
            self._cap = cap if wanted == CAP else math.inf

    def _apply(self, kind: str, target_speed: float) -> float:
        if kind == BRAKE:
            return 0.0
        if kind == CAP:
            return min(target_speed, self._cap)
        return target_speed
