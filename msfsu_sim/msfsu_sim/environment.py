"""The embedded simulator, ROS-free: MetaDrive 0.4.3 rendered headless on the CPU.

`SimEnvironment.reset(town, weather, traffic, seed)` builds an episode; `step(steer, throttle, brake)`
advances 0.1 s (10 Hz, one camera frame) and returns an `Observation`: pixel-aligned front-camera RGB,
metric depth and the paper's 5 semantic classes, plus the ego pose, speed and episode events.
Steering follows CARLA (positive = right); MetaDrive's own convention (positive = left) stays inside.
One MetaDrive engine lives per process: changing town rebuilds it (~15-25 s), changing seed, weather
or traffic within a town only resets the episode.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from msfsu_sim import llvmpipe_patches
from msfsu_sim.cameras import RGB, CameraMount, mount_cameras, read_cameras, sensor_config
from msfsu_sim.route import GlobalRoute, build_route
from msfsu_sim.scenarios import SEEDS_PER_TOWN, Town, Traffic, Weather
from msfsu_sim.pedestrians import Pedestrians
from msfsu_sim.semantics import colours_to_classes
from msfsu_sim.weather import apply_weather

FRAME_PERIOD_S = 0.1  # physics 0.02 s x 5 per step


@dataclass(frozen=True)
class Quality:
    """Rendering settings that trade looks for speed on a CPU rasteriser."""

    width: int = 400
    height: int = 300
    shadow_resolution: int = 512  # per shadow split (MetaDrive default 1024)
    terrain: bool = True  # the road surface and lane markings are drawn by the terrain shader


@dataclass(frozen=True)
class EpisodeEvents:
    crash_vehicle: bool = False
    crash_human: bool = False
    crash_object: bool = False
    out_of_road: bool = False
    arrived: bool = False

    @property
    def collision(self) -> bool:
        return self.crash_vehicle or self.crash_human or self.crash_object


@dataclass
class Observation:
    frame: int
    time_s: float
    rgb: np.ndarray  # (H, W, 3) uint8
    depth: np.ndarray  # (H, W) float32 metres along the optical axis
    class_ids: np.ndarray  # (H, W) uint8, paper classes
    position: np.ndarray  # (2,) metres
    yaw: float  # rad, counter-clockwise from +x
    speed: float  # m/s
    events: EpisodeEvents = field(default_factory=EpisodeEvents)
    route_completion: float = 0.0


class SimEnvironment:
    def __init__(self, quality: Quality = Quality(), mount: CameraMount = CameraMount()) -> None:
        llvmpipe_patches.apply(quality.shadow_resolution)
        self.quality = quality
        self.mount = mount
        self._env = None
        self._town: Town | None = None
        self._pedestrians = None
        self.route: GlobalRoute | None = None
        self.frame = 0

    def _config(self, town: Town) -> dict:
        from metadrive.component.map.base_map import BaseMap
        from metadrive.component.map.pg_map import MapGenerateMethod
        from metadrive.manager.traffic_manager import TrafficMode
        from metadrive.obs.state_obs import LidarStateObservation

        return dict(
            use_render=False, image_observation=True, multi_thread_render=False,
            agent_observation=LidarStateObservation,  # keeps MetaDrive from reading the camera a second time
            sensors=sensor_config(self.quality.width, self.quality.height),
            vehicle_config=dict(image_source=RGB, lidar=dict(num_lasers=0, distance=0)),
            window_size=(64, 64), stack_size=1, show_terrain=self.quality.terrain,
            show_interface=False, show_logo=False, show_fps=False, log_level=50,
            map_config={BaseMap.GENERATE_TYPE: MapGenerateMethod.BIG_BLOCK_SEQUENCE,
                        BaseMap.GENERATE_CONFIG: town.blocks, BaseMap.LANE_NUM: 2, BaseMap.LANE_WIDTH: 3.5,
                        "exit_length": 50},
            start_seed=town.first_seed, num_scenarios=SEEDS_PER_TOWN,
            random_traffic=False, traffic_mode=TrafficMode.Respawn,
            crash_vehicle_done=False, crash_object_done=False, out_of_road_done=False,
            horizon=None,
        )

    def reset(self, town: Town, weather: Weather, traffic: Traffic, seed: int) -> Observation:
        """Start an episode; `seed` (offset within the town) fixes geometry, traffic and route."""
        from metadrive.envs.metadrive_env import MetaDriveEnv

        if self._env is None or town != self._town:
            self.close()
            config = self._config(town)
            config["traffic_density"] = traffic.vehicle_density
            self._env = MetaDriveEnv(config)
            self._town = town
        self._clear_pedestrians()
        self._env.config["traffic_density"] = traffic.vehicle_density
        self._env.reset(seed=town.first_seed + seed % SEEDS_PER_TOWN)
        engine, agent = self._env.engine, self._env.agent
        mount_cameras(engine, agent, self.mount)
        apply_weather(engine, weather)
        lane_index = agent.navigation.current_lane.index[-1] if agent.navigation.current_lane else 0
        self.route = build_route(engine.current_map.road_network, list(agent.navigation.checkpoints), lane_index)
        self._pedestrians = Pedestrians(engine, self.route, traffic.pedestrians, np.random.default_rng(seed))
        self.frame = 0
        return self._observe(EpisodeEvents(), 0.0)

    def step(self, steer: float, throttle: float, brake: float) -> Observation:
        """Apply a CARLA-convention control for one frame (0.1 s)."""
        action = [-float(np.clip(steer, -1.0, 1.0)), float(np.clip(throttle, 0.0, 1.0) - np.clip(brake, 0.0, 1.0))]
        self._pedestrians.step(self._env.agent.position)
        _, _, _, _, info = self._env.step(action)
        self.frame += 1
        events = EpisodeEvents(
            crash_vehicle=bool(info.get("crash_vehicle")), crash_human=bool(info.get("crash_human")),
            crash_object=bool(info.get("crash_object")), out_of_road=bool(info.get("out_of_road")),
            arrived=bool(info.get("arrive_dest")),
        )
        return self._observe(events, float(info.get("route_completion", 0.0)))

    def _observe(self, events: EpisodeEvents, route_completion: float) -> Observation:
        engine, agent = self._env.engine, self._env.agent
        rgb, depth, colours = read_cameras(engine)
        return Observation(
            frame=self.frame, time_s=self.frame * FRAME_PERIOD_S, rgb=rgb, depth=depth,
            class_ids=colours_to_classes(colours), position=np.asarray(agent.position[:2], np.float64),
            yaw=float(agent.heading_theta), speed=float(agent.speed), events=events,
            route_completion=route_completion,
        )

    @property
    def traffic_vehicles(self) -> list:
        """Other vehicles of the episode (objects with .position, .heading_theta, .speed)."""
        from metadrive.component.vehicle.base_vehicle import BaseVehicle

        agent = self._env.agent
        others = self._env.engine.get_objects(lambda obj: isinstance(obj, BaseVehicle) and obj is not agent)
        return list(others.values())

    @property
    def pedestrians(self) -> list:
        return self._pedestrians.objects if self._pedestrians else []

    def _clear_pedestrians(self) -> None:
        if self._pedestrians is not None:
            self._pedestrians.clear()
            self._pedestrians = None

    def close(self) -> None:
        if self._env is not None:
            self._clear_pedestrians()
            self._env.close()
            self._env = None
            self._town = None
