"""ROS-free wrapper of MetaDrive: reset a town/weather/traffic/seed, step with CARLA-style controls,
get pixel-aligned RGB / metric depth / 5-class ids, odometry, flags and the route with RoadOptions.

What reset and step take and give is msfsu_sim.sim_types'; the weather's look (light, fog, wet asphalt) is
msfsu_sim.weather's; this module drives the engine."""

from __future__ import annotations

import math
import os
import time

import numpy as np

from msfsu_common.processes import interrupts_deferred
from msfsu_control.route_tracker import RouteTracker, RouteTrackerConfig
from msfsu_sim import cameras, light_meshes, metadrive_compat, physics_world
from msfsu_common.camera_geometry import CameraView, FrontCamera
from msfsu_sim.clearance import DEFAULT_CLEARANCE, SpawnClearance
from msfsu_sim.route import Route, route_from_checkpoints
from msfsu_sim.route_catalog import SPAWN_LONGITUDE_M
from msfsu_sim.route_catalog import RoadRoute, map_config, road_routes
from msfsu_sim.scene import PEDESTRIAN, VEHICLE, Obstacle, path_ahead, waiting_for
from msfsu_sim.scenarios import TOWNS, TRAFFIC, WEATHERS, Town, Weather
from msfsu_sim.scenario_spec import ScenarioSpec
from msfsu_sim.semantics import colours_to_class_ids
# the environment's interface: what reset and step take and give (msfsu_sim.sim_types), imported from here too
from msfsu_sim.sim_types import (STEP_S, Observation, Odometry, Quality, RouteGeometry, RouteSpec,  # noqa: F401
                                 SimConfig)
from msfsu_sim.weather import apply_fog, apply_weather, wet_road_texture  # noqa: F401
from msfsu_sim.timing import StageClock, TimedTaskManager

PLAN_WITHIN_M = 90.0  # traffic cars this close to the ego carry their planned path (Obstacle.plan) ...
PLAN_LENGTH_M = 90.0  # ... this long: 10 s at 9 m/s
COLLISION_KEYS = {"vehicle": "crash_vehicle", "pedestrian": "crash_human", "object": "crash_object"}  # MetaDrive info
# Strikes of the static layout: MetaDrive reports them but does not end the episode (data collection goes on);
# the closed-loop rules (routes v3) fail an episode on them like on other collisions.
STATIC_COLLISION_KEYS = {"sidewalk": "crash_sidewalk", "building": "crash_building"}


DEFAULT_SPAWN = dict(spawn_lane_index=(">", ">>", 0), spawn_longitude=SPAWN_LONGITUDE_M, destination=None)


def _simulated_clock() -> None:
    """Panda3D's clock advances one simulator step (STEP_S) per frame instead of following the wall clock.

    The clock drives the pedestrians' walk animation: on the wall clock a walker's pose depended on how fast
    the machine rendered, so the same episode gave different images from run to run (and a network fed those
    images could drive differently). Physics has its own fixed step and is unaffected.
    """
    from panda3d.core import ClockObject

    clock = ClockObject.get_global_clock()
    clock.set_mode(ClockObject.M_non_real_time)
    clock.set_dt(STEP_S)


def _restart_pedestrian_animation() -> None:
    """Start the walk cycle from its first frame at every reset (MetaDrive shares one animated model between
    all pedestrians of the process, started when the first one spawned): the pose depends on the episode's
    steps only, not on what ran before it."""
    from metadrive.component.traffic_participants.pedestrian import Pedestrian

    for model in Pedestrian._MODEL.values():
        control = model.get_anim_control("Take 001")
        if control is not None and control.get_play_rate() != 0:
            control.loop(True)


def actor_name(obj: object) -> str:
    """Who a participant is, stable from run to run: the role its manager gave it (msfsu_role: "walker 3",
    "crosser 1", "traffic car 12", a scenario's "pedestrian crossing from the left"), else its kind."""
    role = getattr(obj, "msfsu_role", "")
    if role:
        return role
    from metadrive.component.traffic_participants.pedestrian import Pedestrian

    return "pedestrian" if isinstance(obj, Pedestrian) else "vehicle"


class SimEnvironment:
    """One MetaDrive engine per process (MetaDrive's limit); the env is rebuilt when the town changes."""

    def __init__(self, config: SimConfig | None = None) -> None:
        self.config = config or SimConfig()
        self._env = None
        self._town: Town | None = None
        self._weather: Weather | None = None
        self.route: Route | None = None
        self.tracker: RouteTracker | None = None
        self._step = 0
        self._render = True
        self._wet_textures: dict[float, object] = {}  # wetness -> asphalt texture of the current engine
        self.clock = StageClock()  # wall time per stage of reset() and step()

    # ----- episode -----
    # Both run Panda3D's task loop: a stop signal waits for the end of the call (no traceback from inside a task).
    @interrupts_deferred()
    def reset(self, town: str, weather: str, traffic: str, seed: int, route: RouteSpec | None = None,
              clearance: SpawnClearance = DEFAULT_CLEARANCE, render: bool = True,
              scenario: ScenarioSpec | None = None) -> Observation:
        """Start an episode; `seed` fixes traffic and pedestrians (the town fixes the map).

        No vehicle or pedestrian is placed inside `clearance` of the ego and the first metres of its route.
        `render=False` runs the episode blind: no camera renders, observations carry no images (rgb, depth and
        semantic_ids are None), for a driver that reads the scene itself (the expert: rendering is most of a
        step, benchmarks/simulator.py). The same seed drives the same episode either way.

        Without `route` the ego drives MetaDrive's default route of the map (start of the first block to a
        random exit of the last one, fixed by the map seed); with it, from its start to its destination.

        `scenario` (msfsu_sim.scripted) adds its scripted actor and starts the ego at the scenario's speed.
        """
        town_spec, self._weather, traffic_spec = TOWNS[town], WEATHERS[weather], TRAFFIC[traffic]
        if self._env is None or town_spec != self._town:
            with self.clock.stage("reset: new engine"):
                self.close()
                self._env = self._make_env(town_spec)
                self._town = town_spec
                self._env.lazy_init()
                metadrive_compat.time_tasks(self._env.engine, lambda tasks: TimedTaskManager(tasks, self.clock))
                # no episode inherits Bullet state
                metadrive_compat.renew_worlds_each_reset(self._env.engine, physics_world.renew)
                # MetaDrive's asset loader sets PYTHONUTF8="on", which CPython rejects at start-up: every Python
                # process started afterwards (collect workers, launched nodes) would die. "1" means the same.
                os.environ["PYTHONUTF8"] = "1"
                self._apply_quality()
                _simulated_clock()
        env = self._env
        env.config["traffic_density"] = traffic_spec.vehicle_density
        engine = env.engine
        # random_traffic=True keeps MetaDrive from reseeding traffic with the (fixed) map seed: seed it here.
        from metadrive.manager.base_manager import BaseManager

        BaseManager.seed(engine.traffic_manager, seed)
        engine.traffic_manager.configure(clearance)
        pedestrians = engine.managers["msfsu_pedestrians"]
        BaseManager.seed(pedestrians, seed)
        pedestrians.configure(traffic_spec.walkers, traffic_spec.crossers, clearance)
        engine.managers["msfsu_scenario"].configure(scenario)
        spawn = DEFAULT_SPAWN if route is None else dict(
            spawn_lane_index=(*route.start, route.lane), spawn_longitude=route.longitude_m,
            destination=route.destination)
        env.config["agent_configs"]["default_agent"].update(spawn)
        with self.clock.stage("reset: episode"):
            env.reset(seed=town_spec.map_seed)
        if not self.config.quality.anisotropic_sidewalks:  # after the reset: each new block sets 8x again
            metadrive_compat.sidewalk_filtering(engine, metadrive_compat.ANISOTROPIC_DEGREE)
        _restart_pedestrian_animation()
        if scenario is not None and scenario.initial_speed_mps > 0:
            agent = env.agent
            agent.set_velocity([math.cos(agent.heading_theta), math.sin(agent.heading_theta)],
                               scenario.initial_speed_mps)
        self._apply_weather(self._weather)
        cameras.mount_cameras(engine, env.agent, self.config.mount)
        self._render = render
        cameras.set_active(engine, render)
        navigation = env.agent.navigation
        self.route = route_from_checkpoints(engine.current_map.road_network.graph, navigation.checkpoints,
                                            env.agent.lane_index[2])
        self.tracker = RouteTracker(self.route.poses[:, :2], self.route.options, RouteTrackerConfig())
        self._step = 0
        engine.taskMgr.step()  # render the first frame with cameras mounted and weather set
        return self._observe({})

    @interrupts_deferred()
    def step(self, steer: float, throttle: float, brake: float) -> Observation:
        """Advance 0.1 s. steer in [-1, 1] positive right (CARLA); throttle, brake in [0, 1]."""
        acceleration = float(np.clip(throttle, 0, 1)) - float(np.clip(brake, 0, 1))
        started = time.perf_counter()
        render_before = self.clock.seconds["render"]
        _, _, _, _, info = self._env.step([-float(np.clip(steer, -1, 1)), acceleration])
        rendered = self.clock.seconds["render"] - render_before
        self.clock.add("physics+traffic", time.perf_counter() - started - rendered)
        self._step += 1
        return self._observe(info)

    def road_routes(self) -> list[RoadRoute]:
        """Every start/destination pair of the town loaded by the last reset (msfsu_sim.route_catalog, the
        catalog the benchmark's routes come from), in a stable order."""
        if self._env is None:
            raise RuntimeError("no town loaded: reset first")
        network = self._env.engine.current_map.road_network
        return list(road_routes(network.graph, network.shortest_path))

    def close(self) -> None:
        if self._env is not None:
            self._env.close()
            self._env = None
            self._wet_textures.clear()

    # ----- scene queries for the expert -----
    def obstacles(self, plan_within_m: float = PLAN_WITHIN_M) -> list[Obstacle]:
        """Traffic vehicles and pedestrians (everything with a body except the ego car); the traffic cars
        within `plan_within_m` of the ego carry the path their lanes will take them (Obstacle.plan)."""
        from metadrive.component.traffic_participants.pedestrian import Pedestrian
        from metadrive.component.vehicle.base_vehicle import BaseVehicle

        from msfsu_sim.traffic import planned_path

        engine, ego = self._env.engine, self._env.agent
        graph = engine.current_map.road_network.graph
        scenario = engine.managers["msfsu_scenario"]
        ego_xy = np.asarray(ego.position)
        found = []
        for obj in engine.get_objects(lambda o: isinstance(o, (BaseVehicle, Pedestrian))).values():
            if obj is ego:
                continue
            vx, vy = obj.velocity
            kind = PEDESTRIAN if isinstance(obj, Pedestrian) else VEHICLE
            length, width = (0.8, 0.8) if kind == PEDESTRIAN else (float(obj.LENGTH), float(obj.WIDTH))
            plan = scenario.plan_of(obj)  # a scripted actor goes where its script takes it
            if plan is None and kind == VEHICLE and np.linalg.norm(np.asarray(obj.position) - ego_xy) < plan_within_m:
                plan = planned_path(obj, graph, PLAN_LENGTH_M)
            found.append(Obstacle(float(obj.position[0]), float(obj.position[1]), float(vx), float(vy), length,
                                  width, float(obj.heading_theta), kind, plan, actor_name(obj)))
        return found

    # ----- the route and the scene, as an episode asks about them -----
    def route_geometry(self) -> RouteGeometry:
        """The route of the episode started by the last reset."""
        tracker = self.tracker
        return RouteGeometry(self.route.poses[:, :2], tuple(tracker.junction_spans()), tracker.config.lookahead_m,
                             tracker.length_m, tracker.point_at)

    def waiting_for(self) -> str:
        """What the ego legitimately waits for on its route ahead ("vehicle", "pedestrian"; "" nothing): msfsu_sim.scene's
        rule, on this step's participants."""
        return waiting_for(self.tracker, self.obstacles())

    def anyone_near_path(self, ahead_m: float, within_m: float) -> bool:
        """Is a vehicle or pedestrian within `within_m` of the route's next `ahead_m` metres from the ego's progress?"""
        path = path_ahead(self.tracker, self.tracker.progress_m, self.tracker.progress_m + ahead_m)
        points = np.array([(p.x, p.y) for p in self.participants()]).reshape(-1, 2)
        return bool(len(points)) and bool(np.linalg.norm(points[:, None] - path.points[None], axis=2).min() <= within_m)

    def participants(self) -> list[Obstacle]:
        """Every traffic participant as it stands (Obstacle without plans): what the step's telemetry looks at."""
        return self.obstacles(plan_within_m=0.0)

    def hit_actors(self) -> list[str]:
        """Names (actor_name) of the vehicles and pedestrians the ego car touches now: who it collided with."""
        from metadrive.utils.utils import get_object_from_node

        agent = self._env.agent
        contacts = self._env.engine.physics_world.dynamic_world.contactTest(agent.chassis.node(), True)
        names = []
        for contact in contacts.getContacts():
            for node in (contact.getNode0(), contact.getNode1()):
                try:
                    obj = get_object_from_node(node)
                except (KeyError, AttributeError):
                    continue
                if obj is None or obj is agent or not hasattr(obj, "heading_theta"):
                    continue
                name = actor_name(obj)
                if name not in names:
                    names.append(name)
        return names

    def front_camera(self) -> FrontCamera:
        """The front camera in the vehicle frame (after a reset: the mount is relative to the car's origin)."""
        mount = self.config.mount
        origin_height = float(self._env.agent.origin.getPos()[2])
        return FrontCamera(self.config.width, self.config.height, mount.fov_deg, mount.y, mount.x,
                           mount.z + origin_height, mount.pitch_deg)

    def camera_view(self, crop_top_fraction: float, input_width: int, input_height: int) -> CameraView:
        """The front camera as camera_geometry projects into it, with a network's crop and input size."""
        return self.front_camera().view(crop_top_fraction, input_width, input_height)

    @property
    def odometry(self) -> Odometry:
        agent = self._env.agent
        vx, vy = agent.velocity
        yaw_rate = float(agent.body.getAngularVelocity()[2])
        return Odometry(float(agent.position[0]), float(agent.position[1]), float(agent.heading_theta),
                        float(math.hypot(vx, vy)), yaw_rate)

    # ----- internals -----
    def _make_env(self, town: Town):
        metadrive_compat.patch_classes(light_meshes.model_paths() if self.config.quality.light_meshes else None)
        from metadrive.envs.metadrive_env import MetaDriveEnv
        from metadrive.obs.observation_base import DummyObservation

        from msfsu_sim.pedestrians import PedestrianManager
        from msfsu_sim.scripted import ScenarioManager
        from msfsu_sim.traffic import TrafficManager

        class _Env(MetaDriveEnv):
            def setup_engine(self) -> None:
                super().setup_engine()
                self.engine.update_manager("traffic_manager", TrafficManager())
                self.engine.register_manager("msfsu_pedestrians", PedestrianManager())
                self.engine.register_manager("msfsu_scenario", ScenarioManager())

        no_rays = dict(num_lasers=0, distance=0)
        return _Env(dict(
            map_config=map_config(town),
            start_seed=town.map_seed, num_scenarios=1, random_traffic=True,
            random_lane_width=False, random_lane_num=False, random_spawn_lane_index=False,
            traffic_density=0.0, need_inverse_traffic=True,  # traffic both ways on straight and curved roads
            # MetaDrive keeps removed vehicles for reuse in later episodes; a reused one carries float state
            # of its past (Bullet), so an episode's traffic differed in the last bits with what ran before it
            # and diverged later (outcomes flipped between runs of the same route and seed). New every time.
            force_destroy=True,
            use_render=False, image_observation=True, agent_observation=DummyObservation,
            sensors=cameras.sensor_config(self.config.width, self.config.height, self.config.labels,
                                          self.config.quality.depth_pass),
            multi_thread_render=False, show_interface=False, show_logo=False, show_fps=False,
            show_terrain=self.config.quality.terrain, show_skybox=self.config.quality.sky,
            log_level=40,
            crash_vehicle_done=True, crash_human_done=True, out_of_road_done=True,
            on_continuous_line_done=False,  # touching the centre line during steering noise is not a crash
            vehicle_config=dict(lidar=no_rays, side_detector=no_rays, lane_line_detector=no_rays,
                                show_navi_mark=False, show_dest_mark=False, show_line_to_dest=False),
        ))

    def _apply_quality(self) -> None:
        engine = self._env.engine
        if not self.config.quality.shadows and engine.pssm is not None:
            engine.pssm.buffer.set_active(False)
        if not self.config.quality.main_pass:
            metadrive_compat.skip_main_window_pass(engine)
        if not self.config.quality.shadows:
            metadrive_compat.skip_reset_warm_up_frames(engine)
        metadrive_compat.reuse_terrain(engine)
        if self.config.quality.lean_terrain_shader and not self.config.quality.shadows:
            cameras.set_terrain_shader(engine, cameras.LEAN_TERRAIN_SHADER)
        metadrive_compat.terrain_triangle_width(engine, self.config.quality.terrain_triangle_px)

    def _apply_weather(self, weather: Weather) -> None:
        apply_weather(self._env.engine, weather, self._wet_textures)

    def _observe(self, info: dict) -> Observation:
        engine, clock = self._env.engine, self.clock
        rgb = depth = ids = None
        if self._render:
            with clock.stage("read rgb"):
                rgb = cameras.read_rgb(engine)
            with clock.stage("read depth"):
                depth = cameras.read_depth(engine)
            if self.config.labels:
                with clock.stage("read ids"):
                    ids = colours_to_class_ids(cameras.read_semantic_colours(engine))
            with clock.stage("fog"):
                rgb = apply_fog(rgb, depth, self._weather)
        odometry = self.odometry
        command = self.tracker.update(odometry.x, odometry.y)
        return Observation(
            step=self._step, time_s=self._step * STEP_S,
            rgb=rgb, depth=depth, semantic_ids=ids,
            odometry=odometry, command=command, route_progress_m=self.tracker.progress_m,
            route_completion=float(info.get("route_completion", 0.0)),
            collision=any(bool(info.get(key)) for key in COLLISION_KEYS.values()),
            out_of_road=bool(info.get("out_of_road", False)),
            arrived=bool(info.get("arrive_dest", False)),
            collision_type=next((name for name, key in COLLISION_KEYS.items() if info.get(key)), ""),
            static_collision=next((name for name, key in STATIC_COLLISION_KEYS.items() if info.get(key)), ""),
            solid_line=self._solid_line(),
            collision_actor=", ".join(self.hit_actors()) if info.get("crash_vehicle") or info.get("crash_human")
            else "",
        )

    def _solid_line(self) -> bool:
        agent = self._env.agent if self._env is not None else None
        return bool(agent is not None and (agent.on_yellow_continuous_line or agent.on_white_continuous_line))
