"""What the simulator environment takes and gives (ROS-free): its configuration, an episode's route
specification, the observation of a step with its odometry, and the route's geometry as a benchmark measures along it.
msfsu_sim.environment drives MetaDrive with them (and names them too)."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from msfsu_common.road_option import RoadOption
from msfsu_sim import cameras
from msfsu_sim.route_catalog import SPAWN_LONGITUDE_M, RoadRoute

STEP_S = 0.1  # 10 Hz: physics 0.02 s x decision_repeat 5


@dataclass(frozen=True)
class Quality:
    """Render settings that trade look for speed (defaults: road surface and lane markings kept)."""

    shadows: bool = False  # PSSM shadow pass: a second render of the scene per frame
    terrain: bool = True  # the road surface and lane markings are drawn by the terrain shader
    sky: bool = True
    terrain_triangle_px: int = 16  # ShaderTerrainMesh target triangle width (MetaDrive: 10)
    light_meshes: bool = True  # traffic, wheels and pedestrians drawn with levels of detail (msfsu_sim.light_meshes)
    # the terrain's RGB shader without the texture reads that never show (same image; shaders/terrain_rgb.frag.glsl)
    lean_terrain_shader: bool = True
    # MetaDrive's 8x anisotropic filter on the sidewalk texture: llvmpipe samples it on a slow path whatever the
    # degree above 1 (2, 4 and 8 draw the same image); off (simulator revision 4), only far sidewalk pixels differ,
    # slightly. What it costs and the two images: benchmarks/simulator.py, mode evaluation_anisotropic_sidewalks
    anisotropic_sidewalks: bool = False
    # MetaDrive's own passes, kept only to measure what they cost (benchmarks/simulator.py, mode "stock"):
    main_pass: bool = False  # the hidden main window's scene pass (far plane 100 km), read by nobody headless
    depth_pass: bool = False  # a second scene render for depth instead of the RGB pass's depth buffer


@dataclass(frozen=True)
class SimConfig:
    width: int = 400
    height: int = 300
    labels: bool = True  # render the semantic pass (5-class ids): data collection needs it, driving does not
    mount: cameras.CameraMount = field(default_factory=cameras.CameraMount)
    quality: Quality = field(default_factory=Quality)


@dataclass(frozen=True)
class RouteSpec:
    """Start and destination of an episode on a town's road graph (MetaDrive node names).

    The ego spawns `longitude_m` along lane `lane` of road `start` = (from node, to node) and MetaDrive's
    navigation plans the shortest path to the end node `destination` (where the episode is "arrived").
    """

    start: tuple[str, str]
    lane: int
    longitude_m: float
    destination: str

    @classmethod
    def along(cls, route: RoadRoute, lane: int = 0, longitude_m: float | None = None) -> RouteSpec:
        """Drive a catalog route (msfsu_sim.route_catalog) from `longitude_m` (default: MetaDrive's spawn
        position) along lane `lane` of its start road."""
        longitude = SPAWN_LONGITUDE_M if longitude_m is None else longitude_m
        return cls((route.checkpoints[0], route.checkpoints[1]), lane, longitude, route.checkpoints[-1])




@dataclass(frozen=True)
class RouteGeometry:
    """The episode's route as a benchmark measures along it (SimEnvironment.route_geometry)."""

    points: np.ndarray  # (N, 2) the route's polyline, map frame
    junction_spans: tuple[tuple[float, float], ...]  # (start, end) arc lengths of each junction crossing
    lookahead_m: float  # how far ahead the route announces a junction's command
    length_m: float
    point_at: Callable[[float], np.ndarray]  # (x, y) at an arc length (clamped to the route)


@dataclass(frozen=True)
class Odometry:
    x: float
    y: float
    yaw: float  # rad, counter-clockwise from the map x axis
    speed: float  # m/s
    yaw_rate: float  # rad/s


@dataclass(frozen=True)
class Observation:
    step: int
    time_s: float  # simulation time of the camera frame
    rgb: np.ndarray | None  # (H, W, 3) uint8; None in a blind episode (reset(render=False))
    depth: np.ndarray | None  # (H, W) float32 metres along the optical axis; None in a blind episode
    semantic_ids: np.ndarray | None  # (H, W) uint8 SemanticClass; None when SimConfig.labels is off
    odometry: Odometry
    command: RoadOption
    route_progress_m: float  # arc length of the ego's projection on the route
    route_completion: float
    collision: bool
    out_of_road: bool
    arrived: bool
    collision_type: str = ""  # "vehicle", "pedestrian" or "object" when `collision`
    static_collision: str = ""  # "sidewalk" (kerb, boundary, guardrail) or "building" when the car strikes one
    solid_line: bool = False  # the car touches a solid (yellow or white) lane line
    collision_actor: str = ""  # who the car collided with (actor_name), when it collided with a vehicle or pedestrian

    @property
    def done(self) -> bool:
        return self.collision or self.out_of_road or self.arrived
