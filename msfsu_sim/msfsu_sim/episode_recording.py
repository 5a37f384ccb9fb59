"""Recording one collected episode into its rosbag2 MCAP bag (paper III-A), labelled by the expert.

The recorded labels (`topics.EXPERT_ACTION`) are always the expert's action for the state reached
(`Expert.act_on`), whoever drove; `topics.NETWORK_DRIVING` flags the frames the network drove,
`topics.DRIVING_ACTION` holds what the network asked for in those frames, and the metadata names the driver,
beta, the round and how the episode ended (`bag_io.END`). Steering noise is injected only into frames the expert
drives.

Which episodes are kept: the paper keeps only clean driving, so an expert-only episode (no network, or beta = 1)
that ends in a collision or off the road is dropped. An on-policy episode that ends so is what DAgger is for: it
is kept without its last second (CRASH_TRIM_S; the states from which the crash could no longer be avoided, whose
labels teach nothing), and dropped only if nothing is left.
"""

from __future__ import annotations

import shutil
from collections import Counter, deque
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from msfsu_common import bag_io, topics
from msfsu_common.camera_geometry import FrontCamera
from msfsu_control.pid import Control
from msfsu_sim import SIMULATOR_REVISION
from msfsu_sim.collection_plan import Episode, bag_path, partial_bag_path
from msfsu_sim.collection_routes import episode_route, route_metadata
from msfsu_sim.environment import STEP_S, Observation, RouteSpec, SimEnvironment
from msfsu_sim.episode_driver import EXPERT, Driver, Pilot
from msfsu_sim.expert import Expert, ExpertAction, SteeringNoise
from msfsu_sim.messages import TYPES, MessageBuilder, rosbags_builder
from msfsu_sim.route_catalog import RoadRoute

if TYPE_CHECKING:
    from msfsu_perception.inference import DrivingModel, Prediction

CRASH_TRIM_S = 1.0  # an on-policy episode ending in a crash loses this much before it
SLOW_MPS = 1.0  # labels below this target speed count as stopping (reported per traffic level)

Message = tuple[str, Any, float]  # (topic, message, log time in s)


@dataclass(frozen=True)
class EpisodeResult:
    episode: Episode
    kept: bool
    reason: str  # arrived / timeout / collision / out_of_road
    steps: int  # steps driven
    route_completion: float
    noisy_steps: int
    frames: int = 0  # frames in the bag (steps minus the trimmed second of a kept crash; 0 when dropped)
    network_frames: int = 0  # of those, driven by the network
    slow_frames: int = 0  # of those, labelled with a target speed below SLOW_MPS
    route: tuple[str, ...] = ()  # checkpoints of the route driven


@dataclass(frozen=True)
class DrivenStep:
    """One step's messages, and what the frame counts need of it."""

    messages: list[Message]
    by_network: bool
    label_speed: float  # the expert label's target speed
    noisy: bool  # steering noise was added to the applied steer


class StepDriver:
    """Drives one step: the expert's label for the state, the pilot's draw of who drives, the steering noise on
    expert-driven steps, and the control the controller applies. The draws happen in the same order every step
    (label, driver draw, noise burst) whoever drives, so an episode is fixed by its seed."""

    def __init__(self, build: MessageBuilder, pilot: Pilot, steering_noise: SteeringNoise | None) -> None:
        self.build, self.pilot, self.steering_noise = build, pilot, steering_noise
        self.expert = Expert()

    def step(self, env: SimEnvironment, obs: Observation) -> tuple[DrivenStep, Control]:
        t = obs.time_s
        label = self.expert.act_on(obs, env)
        by_network = self.pilot.network_drives()
        noise = self.steering_noise
        offset = noise.offset(t) if noise else 0.0  # the burst schedule is the same whoever drives
        noisy = noise is not None and noise.active(t) and not by_network
        prediction = self.pilot.network_action(obs) if by_network else None
        if prediction is not None:
            steer, target_speed = prediction.steer, prediction.target_speed
        else:
            steer, target_speed = label.steer + (offset if noisy else 0.0), label.target_speed
        control = self.pilot.controller.step(steer, target_speed, obs.odometry.speed, STEP_S)
        messages = self._messages(obs, label, control, noisy, prediction)
        return DrivenStep(messages, by_network, label.target_speed, noisy), control

    def _messages(self, obs: Observation, label: ExpertAction, control: Control, noisy: bool,
                  prediction: Prediction | None) -> list[Message]:
        build, t = self.build, obs.time_s
        messages = [(topic, message, t) for topic, message in build.sensors(obs).items()]
        messages += [(topics.EXPERT_ACTION, build.driving_action(t, label), t),
                     (topics.VEHICLE_CONTROL, build.vehicle_control(t, control.throttle, control.steer,
                                                                    control.brake), t),
                     (topics.NOISE_INJECTION, build.flag(noisy), t),
                     (topics.NETWORK_DRIVING, build.flag(prediction is not None), t),
                     (topics.EXPERT_LIMITED_BY, build.text(label.limited_by), t)]
        if prediction is not None:  # what the network asked, beside the expert's label (near misses: DrivingDataset)
            asked = ExpertAction(prediction.steer, prediction.target_speed, label.command)
            messages.append((topics.DRIVING_ACTION, build.driving_action(t, asked), t))
        return messages


class TrimmedBagWriter:
    """Writes steps into the bag `trim` steps late, so that the last `trim` steps can be left out, and counts the
    frames written."""

    def __init__(self, writer: Any, store: Any, trim: int) -> None:
        self._writer, self._store, self._trim = writer, store, trim
        self._connections = {topic: writer.add_connection(topic, msgtype, typestore=store)
                             for topic, msgtype in TYPES.items()}
        self._held: deque[DrivenStep] = deque()
        self.written: Counter[str] = Counter()

    def write(self, topic: str, message: Any, time_s: float) -> None:
        self._writer.write(self._connections[topic], round(time_s * 1e9),
                           self._store.serialize_cdr(message, TYPES[topic]))

    def hold(self, step: DrivenStep) -> None:
        """Queue the step, writing the one that falls out of the last `trim`."""
        self._held.append(step)
        if len(self._held) > self._trim:
            self._write_step(self._held.popleft())

    def flush(self) -> None:
        """Write the held steps (the episode did not end in a crash)."""
        while self._held:
            self._write_step(self._held.popleft())

    def _write_step(self, step: DrivenStep) -> None:
        for message in step.messages:
            self.write(*message)
        self.written.update(frames=1, network_frames=step.by_network, slow_frames=step.label_speed < SLOW_MPS)


def episode_metadata(episode: Episode, route: RoadRoute, driver: Driver, camera: FrontCamera) -> dict[str, object]:
    """The bag's metadata: scenario, seed, route, driver, round, simulator revision, camera (the end is added at
    close)."""
    return {bag_io.SPLIT: episode.split, bag_io.MAP: episode.town, bag_io.WEATHER: episode.weather,
            bag_io.TRAFFIC: episode.traffic, bag_io.SEED: episode.seed, **route_metadata(route),
            **driver.metadata(), bag_io.ROUND: episode.round, bag_io.SIMULATOR_REVISION: SIMULATOR_REVISION,
            bag_io.CAMERA: camera.to_json()}


def end_reason(obs: Observation) -> str:
    """How the episode ended: collision / out_of_road / arrived / timeout."""
    return ("collision" if obs.collision else "out_of_road" if obs.out_of_road
            else "arrived" if obs.arrived else "timeout")


def drive_episode(env: SimEnvironment, obs: Observation, driver: StepDriver, bag: TrimmedBagWriter, max_steps: int,
                  record_from: int) -> tuple[Observation, int]:
    """Drive from `obs` to the episode's end or `max_steps`, handing the steps from `record_from` on to `bag` (the
    route first); returns the last observation and the number of noisy steps."""
    noisy_steps = 0
    while not obs.done and obs.step < max_steps:
        if obs.step == record_from:  # the bag's first message
            bag.write(topics.ROUTE, driver.build.route(obs.time_s, env.route), obs.time_s)
        step, control = driver.step(env, obs)
        noisy_steps += step.noisy
        if obs.step >= record_from:
            bag.hold(step)
        obs = env.step(control.steer, control.throttle, control.brake)
    return obs, noisy_steps


def record_episode(env: SimEnvironment, episode: Episode, output: Path, max_steps: int, noise: bool,
                   driver: Driver = EXPERT, network: DrivingModel | None = None,
                   record_from: int = 0) -> EpisodeResult:
    """Drive one episode (expert, or on-policy with `network`) and write its bag (removed again if dropped).

    Steps before `record_from` are driven the same way but not written (the bag starts there, with the route).
    """
    store = bag_io.msfsu_typestore()
    route = episode_route(env, episode)
    pilot = Pilot(episode.seed, driver.beta if driver.on_policy else 1.0, network if driver.on_policy else None)
    step_driver = StepDriver(rosbags_builder(store), pilot, SteeringNoise(episode.seed) if noise else None)
    partial = partial_bag_path(output, episode)
    shutil.rmtree(partial, ignore_errors=True)
    partial.parent.mkdir(parents=True, exist_ok=True)
    obs = env.reset(episode.town, episode.weather, episode.traffic, episode.seed, RouteSpec.along(route))
    trim = round(CRASH_TRIM_S / STEP_S) if driver.on_policy else 0
    with bag_io.mcap_writer(partial, episode_metadata(episode, route, driver, env.front_camera())) as writer:
        bag = TrimmedBagWriter(writer, store, trim)
        obs, noisy_steps = drive_episode(env, obs, step_driver, bag, max_steps, record_from)
        reason = end_reason(obs)
        crashed = reason in bag_io.CRASH_ENDS
        if not crashed:
            bag.flush()
        writer.set_custom_data(bag_io.METADATA_PREFIX + bag_io.END, reason)  # metadata.yaml is written at close
    written = bag.written
    kept = (not crashed or driver.on_policy) and written["frames"] > 0
    if kept:
        partial.rename(bag_path(output, episode))
    else:
        shutil.rmtree(partial)
        written.clear()
    return EpisodeResult(episode, kept, reason, obs.step, obs.route_completion, noisy_steps, written["frames"],
                         written["network_frames"], written["slow_frames"], route.checkpoints)
