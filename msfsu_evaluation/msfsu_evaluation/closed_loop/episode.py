"""One benchmark episode: reset the simulator to a route, let a driver answer every frame, judge each step.

ROS-free: the driver is either the in-process expert (reference row, reference trajectory) or the
node graph behind msfsu_evaluation.closed_loop.graph_agent. Optionally the episode is filmed
(EpisodeVideo): one video frame per simulator frame, showing what the driver made of it.
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol

import numpy as np

from msfsu_evaluation.closed_loop.episode_record import (AebInterventions, EpisodeResult, EpisodeTiming, FreeRunning,
                                                         SolidLineCrossing)
from msfsu_evaluation.closed_loop.lateral import place_on_route
from msfsu_evaluation.closed_loop.rules import EpisodeJudge, EpisodeRules, Outcome, StepState, timeout_s
from msfsu_evaluation.closed_loop.abilities import route_task
from msfsu_evaluation.closed_loop.suites import SPAWN_CLEARANCE, BenchmarkRoute
from msfsu_evaluation.closed_loop.telemetry import DriverStep, ExpertLabel, TelemetryRecorder
from msfsu_evaluation.video import DriveRenderer, DriveState, VideoWriter
from msfsu_perception.preprocessing import PreprocessConfig
from msfsu_common.camera_geometry import CameraView
from msfsu_sim.environment import Observation, RouteGeometry, RouteSpec, SimEnvironment
from msfsu_sim.expert import Expert
from msfsu_sim.timing import StageClock

Control = tuple[float, float, float]  # steer (positive right), throttle, brake
TRAJECTORY_FIELDS = ("time_s", "x", "y", "yaw", "yaw_rate", "speed")
STANDING_MPS = 0.5  # below this the car needs a reason to wait (rules.StepState.waiting_for)
# Where an episode's wall time goes in the worker (EpisodeTiming.wall_s), in loop order: the simulator's reset and
# steps (physics, rendering, read-back), the driver (a graph: its nodes' resets before the episode, publishing the
# frame, waiting for its control and for its other outputs; "driver" what a driver does not break down), the expert's
# label of the same state, the step's telemetry row, the judge (rules, progress, what the car waits for), the video,
# and what is left of the loop.
STAGES = ("reset", "reset graph", "simulate", "publish", "wait for control", "wait for outputs", "driver",
          "expert label", "telemetry", "judge", "video", "other")


class Driver(Protocol):
    name: str
    needs_images: bool  # False: the driver reads the scene itself and the episode may run blind (faster)

    def begin(self, obs: Observation, env: SimEnvironment) -> None: ...

    def act(self, obs: Observation, env: SimEnvironment) -> Control: ...

    def decision(self, obs: Observation) -> DriveState:
        """What the driver made of the frame it last acted on (steer, target speed, command, segmentation)."""
        ...

    def step_action(self, obs: Observation) -> DriverStep:
        """The action the driver produced for the frame it last acted on, for the step's telemetry."""
        ...

    def camera_view(self, env: SimEnvironment) -> CameraView:
        """The camera and the crop its network sees (telemetry's in-view / in-crop)."""
        ...

    def end(self, obs: Observation) -> None: ...

    def free_running_record(self) -> dict | None:
        """The episode's free-running figures (msfsu_sim.pacing.RealTimePacer.record), None in lockstep."""
        ...

    def timing(self) -> tuple[dict[str, float], dict[str, float]]:
        """Since begin(): wall seconds of the driver's own stages (of STAGES; {}: none broken down) and CPU seconds of
        the processes it drives with besides the worker (a graph's nodes by name; {}: none)."""
        ...


class ExpertDriver:
    """The data-collection expert (pure pursuit + IDM + the control node's speed PID), no noise, no ROS."""

    name = "expert"
    needs_images = False  # it drives on the simulator's ground truth
    unanswered_frames = 0

    def __init__(self) -> None:
        self.expert = Expert()
        self.action = None

    def begin(self, obs: Observation, env: SimEnvironment) -> None:
        self.expert.reset()

    def act(self, obs: Observation, env: SimEnvironment) -> Control:
        self.action, longitudinal = self.expert.drive(obs, env)
        return self.action.steer, longitudinal.throttle, longitudinal.brake

    def decision(self, obs: Observation) -> DriveState:
        """The expert's action; it has no segmentation: the video shows the simulator's ground truth."""
        return DriveState(obs.time_s, steer=self.action.steer, target_speed_mps=self.action.target_speed,
                          command=int(self.action.command), action_source="expert",
                          segmentation=obs.semantic_ids, segmentation_label="ground truth")

    def step_action(self, obs: Observation) -> DriverStep:
        if self.action is None:  # a subclass that drives otherwise
            return DriverStep(math.nan, math.nan, None, None)
        return DriverStep(self.action.steer, self.action.target_speed, int(self.action.command), 0)

    def label(self) -> ExpertLabel | None:
        """Its own action as the telemetry's expert columns."""
        if self.action is None:
            return None
        return ExpertLabel(self.action.steer, self.action.target_speed, self.action.limited_by)

    def camera_view(self, env: SimEnvironment) -> CameraView:
        """The default preprocessing's crop (the shipped networks' crop; the expert sees no image)."""
        config = PreprocessConfig()
        return env.camera_view(config.crop_top_fraction, config.input_width, config.input_height)

    def end(self, obs: Observation) -> None:
        pass

    def free_running_record(self) -> None:
        return None  # the in-process expert always drives in lockstep

    def timing(self) -> tuple[dict[str, float], dict[str, float]]:
        return {}, {}  # it drives in the worker, within the "driver" stage


class EpisodeVideo:
    """The MP4 of one episode (msfsu_evaluation.video): each simulator frame with the driver's decision.

    `close()` keeps the file, `discard()` removes it (e.g. a successful episode when only failures are kept).
    """

    def __init__(self, path: Path) -> None:
        self.writer = VideoWriter(path)
        self.renderer = DriveRenderer()

    def begin(self, geometry: RouteGeometry) -> None:
        self.renderer.set_route(geometry.points)

    def add(self, obs: Observation, state: DriveState, control: Control | None = None) -> None:
        odometry = obs.odometry
        state = dataclasses.replace(
            state, time_s=obs.time_s, speed_mps=odometry.speed, pose=(odometry.x, odometry.y, odometry.yaw),
            command=int(obs.command) if state.command is None else state.command,
            throttle=None if control is None else control[1], brake=None if control is None else control[2])
        self.writer.write(self.renderer.render(obs.rgb, state))

    def close(self) -> Path | None:
        return self.writer.close()

    def discard(self) -> None:
        self.writer.discard()


def outcome_text(outcome: Outcome) -> str:
    kind = f"{outcome.status} ({outcome.collision_type})" if outcome.collision_type else outcome.status
    return f"{kind.upper()} at {outcome.time_s:.1f} s, {outcome.route_completion:.0%} of the route"


class RouteDistances:
    """Where a route's progress was driven: metres under each command and in each place of SOLID_LINE_PLACES (the
    denominators of per-km rates by command or place), and the command and place of every solid-line crossing's
    start. Each step's forward progress counts under the command and place of the step it started from."""

    def __init__(self, geometry: RouteGeometry, start_progress_m: float) -> None:
        self.spans, self.lookahead_m = list(geometry.junction_spans), geometry.lookahead_m
        self.start_progress_m = start_progress_m
        self.by_command: dict[str, float] = {}
        self.by_place: dict[str, float] = {}
        self.solid_lines: list[SolidLineCrossing] = []
        self._last: tuple[float, str, str] | None = None

    def add(self, obs: Observation, crossing_began: bool) -> None:
        place = place_on_route(obs.route_progress_m, self.spans, self.lookahead_m)
        if self._last is not None:
            progress, command, last_place = self._last
            metres = max(obs.route_progress_m - progress, 0.0)
            self.by_command[command] = self.by_command.get(command, 0.0) + metres
            self.by_place[last_place] = self.by_place.get(last_place, 0.0) + metres
        self._last = (obs.route_progress_m, obs.command.name, place)
        if crossing_began:
            self.solid_lines.append(SolidLineCrossing(round(obs.time_s, 2),
                                                      round(obs.route_progress_m - self.start_progress_m, 1),
                                                      obs.command.name, place))

    @staticmethod
    def rounded(metres: dict[str, float]) -> dict[str, float]:
        return {key: round(value, 1) for key, value in sorted(metres.items())}


def _result(agent: str, route: BenchmarkRoute, outcome: Outcome, steps: int, distance: float, limit_s: float,
            wall_s: float, unanswered: int, free_running: dict | None, driven: RouteDistances,
            collision_actor: str, aeb: AebCount, timing: EpisodeTiming) -> EpisodeResult:
    """The episode's record, rounded as episodes.jsonl holds it (the worker stamps itself on later)."""
    hit = collision_actor if outcome.collision_type in ("vehicle", "pedestrian") else ""
    return EpisodeResult(agent, route.key, outcome.status, outcome.success, round(outcome.time_s, 2), steps,
                         round(outcome.route_completion, 4), outcome.collision_type, round(distance, 2),
                         round(limit_s, 1), round(wall_s, 1), unanswered,
                         None if free_running is None else FreeRunning(**free_running), outcome.solid_line_crossings,
                         tuple(driven.solid_lines), driven.rounded(driven.by_command), driven.rounded(driven.by_place),
                         collision_actor=hit, aeb=AebInterventions(aeb.brakes, aeb.caps, aeb.false_brakes, aeb.false_caps)
                         if aeb.seen else None, timing=timing)


class AebCount:
    """The emergency brake's interventions of an episode: each start of a brake or a cap, and the brakes and caps
    with no vehicle or pedestrian within FALSE_BRAKE_M of the car's path ahead by the simulator's ground truth (false
    ones: a cap for a crossing stops the car as a brake does)."""

    FALSE_BRAKE_M = 15.0
    PATH_M = 40.0  # the path ahead searched, from the car's route progress

    def __init__(self) -> None:
        self.brakes = self.caps = self.false_brakes = self.false_caps = 0
        self.seen = False  # the driver has an emergency brake
        self._last = "none"

    def add(self, decision: str | None, env: SimEnvironment) -> None:
        if decision is None:
            return
        self.seen = True
        if decision != self._last and decision in ("brake", "cap"):
            false = not env.anyone_near_path(self.PATH_M, self.FALSE_BRAKE_M)
            if decision == "brake":
                self.brakes, self.false_brakes = self.brakes + 1, self.false_brakes + false
            else:
                self.caps, self.false_caps = self.caps + 1, self.false_caps + false
        self._last = decision


def _row(obs: Observation) -> tuple[float, ...]:
    odometry = obs.odometry
    return obs.time_s, odometry.x, odometry.y, odometry.yaw, odometry.yaw_rate, odometry.speed


@dataclass
class EpisodeOutput:
    """What an episode leaves besides its record: the trajectory (T, 6) with TRAJECTORY_FIELDS per simulator frame,
    and its telemetry (closed_loop.telemetry: one row per step the driver acted on)."""

    trajectory: np.ndarray
    telemetry: TelemetryRecorder


def run_episode(env: SimEnvironment, route: BenchmarkRoute, driver: Driver,
                blocked_s: float = EpisodeRules.blocked_s,
                video: EpisodeVideo | None = None,
                on_step: Callable[[], None] | None = None,
                expert_labels: bool = True) -> tuple[EpisodeResult, EpisodeOutput]:
    """Drive `route` to its end; (result, trajectory and telemetry).

    `on_step` is called after every simulator step (the benchmark's worker heartbeat). `expert_labels`: a network's
    telemetry also holds the expert's action in the same state (the expert's own holds its action either way).

    With `video`, every frame is filmed (the last one with the outcome); the caller closes or discards it.
    Nothing renders when neither the driver nor a video needs images.
    """
    task = route_task(route)
    started, cpu_started = time.monotonic(), time.process_time()
    clock = StageClock()
    with clock.stage("reset"):
        obs = env.reset(route.town, route.weather, task.traffic, route.seed,
                        RouteSpec(route.start, route.lane, route.longitude_m, route.destination), SPAWN_CLEARANCE,
                        render=driver.needs_images or video is not None, scenario=route.scenario)
    limit_s = timeout_s(route.length_m, task.timeout_speed_kmh, task.timeout_margin_s)
    judge = EpisodeJudge(EpisodeRules(route.length_m, limit_s, blocked_s=blocked_s))
    geometry = env.route_geometry()
    # a scenario ends at its goal, a route at its destination
    goal = geometry.point_at(geometry.length_m if route.scenario is None else route.scenario.goal_m)
    start_progress = obs.route_progress_m
    with clock.stage("driver"):
        driver.begin(obs, env)
    if video is not None:
        video.begin(geometry)
    rows = [_row(obs)]
    driven = RouteDistances(geometry, start_progress)
    telemetry = TelemetryRecorder(driver.camera_view(env))
    labeller = Expert() if expert_labels and not isinstance(driver, ExpertDriver) else None
    aeb = AebCount()
    while True:
        with clock.stage("judge"):
            distance = math.hypot(goal[0] - obs.odometry.x, goal[1] - obs.odometry.y)
            # Only a car that stands needs a reason to (the blocked rule): ask the scene only then.
            waiting = env.waiting_for() if obs.odometry.speed < STANDING_MPS else ""
            outcome = judge.update(StepState(obs.time_s, distance, obs.route_progress_m - start_progress,
                                             obs.collision_type, obs.out_of_road, obs.arrived, waiting,
                                             obs.static_collision, obs.solid_line))
            driven.add(obs, crossing_began=judge.solid_line_crossings > len(driven.solid_lines))
        if outcome is not None:  # covers every way the simulator ends an episode (obs.done)
            break
        with clock.stage("driver"):
            control = driver.act(obs, env)
        decision = _record_step(telemetry, obs, env, driver, control, labeller, clock)
        with clock.stage("judge"):
            aeb.add(decision, env)
        if video is not None:
            with clock.stage("video"):
                video.add(obs, driver.decision(obs), control)
        with clock.stage("simulate"):
            obs = env.step(*control)
        rows.append(_row(obs))
        if on_step is not None:
            on_step()
    with clock.stage("driver"):
        driver.end(obs)
    if video is not None:
        with clock.stage("video"):
            video.add(obs, DriveState(obs.time_s, status=outcome_text(outcome)))
    wall_s = time.monotonic() - started
    timing = _timing(clock, driver, wall_s, time.process_time() - cpu_started)
    result = _result(driver.name, route, outcome, obs.step, distance, limit_s, wall_s,
                     driver.unanswered_frames, driver.free_running_record(), driven, obs.collision_actor, aeb, timing)
    return result, EpisodeOutput(np.asarray(rows, np.float64), telemetry)


def _timing(clock: StageClock, driver: Driver, wall_s: float, worker_cpu_s: float) -> EpisodeTiming:
    """The episode's EpisodeTiming: the driver's own stages in place of the part of "driver" they cover, "other" what
    no stage covers; CPU seconds of the worker and of the driver's processes."""
    stages, cpu = driver.timing()
    seconds = dict(clock.seconds)
    if stages:
        seconds["driver"] = max(0.0, seconds.get("driver", 0.0) - sum(stages.values()))
        seconds.update(stages)
    seconds["other"] = max(0.0, wall_s - sum(seconds.values()))
    return EpisodeTiming({stage: round(seconds[stage], 3) for stage in STAGES if seconds.get(stage)},
                         {name: round(value, 3) for name, value in {"worker": worker_cpu_s, **cpu}.items()})


def _record_step(telemetry: TelemetryRecorder, obs: Observation, env: SimEnvironment, driver: Driver,
                 control: Control, labeller: Expert | None, clock: StageClock) -> str | None:
    """The step's telemetry row: the driver's action, the control, the expert's label, who is ahead; the emergency
    brake's decision (None: the driver has none)."""
    with clock.stage("expert label"):
        if isinstance(driver, ExpertDriver):
            label = driver.label()
        elif labeller is not None:
            action = labeller.act_on(obs, env)
            label = ExpertLabel(action.steer, action.target_speed, action.limited_by)
        else:
            label = None
    odometry = obs.odometry
    with clock.stage("driver"):
        action = driver.step_action(obs)
    with clock.stage("telemetry"):
        telemetry.add(obs.time_s, odometry.speed, int(obs.command), action, control, label,
                      env.participants(), (odometry.x, odometry.y, odometry.yaw), obs.depth)
    return action.aeb_decision
