"""`msfsu-collect`: driving episodes -> one rosbag2 MCAP bag per episode (paper III-A), labelled by the expert.

Episodes are planned from (split, towns, weathers, traffic levels, N, round), each with a seed derived from
the base seed, its name and its round, so a run is deterministic and can resume: finished bags are skipped
and bags are written under `<split>/.partial/` and renamed only when complete.

Routes: each episode drives a route drawn (by its seed) from its town's start/destination pairs
(`msfsu_sim.route_catalog`, the catalog the benchmark's routes come from) that cross at least one junction,
leave room for the spawn on the start road and are at most MAX_ROUTE_M long. The bag's metadata names the
route (start road, destination, junction options, length).

Who drives: the expert, by default. On-policy rounds (DAgger, Ross et al. 2011): with `--driver CHECKPOINT
--beta B`, each step is driven by the expert with probability B and by the network otherwise (one seeded draw
per step). The network runs in this process through the perception node's per-frame function
(`msfsu_perception.frame_inference.infer_frame`, at the node's default `max_invalid_depth_fraction`), and its
steer and target speed go through the control node's speed PID (`ActionController`), the one PID the expert's
target speed goes through too. The recorded labels (`topics.EXPERT_ACTION`) are
always the expert's action for the state reached (`Expert.act_on`); `topics.NETWORK_DRIVING` flags the frames
the network drove, `topics.DRIVING_ACTION` holds what the network asked for in those frames, and the metadata
names the driver, B, the round and how the episode ended (`bag_io.END`). Steering noise is injected only into
frames the expert drives.

Which episodes are kept: the paper keeps only clean driving, so an expert-only episode (no network, or B = 1)
that ends in a collision or off the road is dropped (listed in `dropped.jsonl`). An on-policy episode that
ends so is what DAgger is for: it is kept without its last second (CRASH_TRIM_S; the states from which the
crash could no longer be avoided, whose labels teach nothing), and dropped only if nothing is left.
"""

from __future__ import annotations

import argparse
import json
import multiprocessing
import os
import random
import shutil
import sys
import zlib
from collections import Counter, deque
from collections.abc import Iterator, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from msfsu_common import bag_io, topics
from msfsu_common.processes import interrupt_on_signals, tie_to_parent
from msfsu_control.pid import ActionController
from msfsu_perception.frame_inference import infer_frame
from msfsu_sim import SIMULATOR_REVISION, UNRECORDED_REVISION
from msfsu_sim.environment import STEP_S, Observation, Quality, RouteSpec, SimConfig, SimEnvironment
from msfsu_sim.expert import Expert, ExpertAction, SteeringNoise
from msfsu_sim.messages import TYPES, rosbags_builder
from msfsu_sim.route_catalog import MAX_ROUTE_M, SPAWN_LONGITUDE_M, RoadRoute
from msfsu_sim.scenarios import (HELDOUT_TOWNS, HELDOUT_WEATHERS, TOWNS, TRAFFIC, TRAIN_TOWNS, TRAIN_WEATHERS,
                                 WEATHERS)

if TYPE_CHECKING:
    from msfsu_perception.inference import DrivingModel, Prediction

DROPPED_LOG = "dropped.jsonl"
PARTIAL_DIR = ".partial"
SPAWN_ROOM_M = 5.0  # the start road must reach this far beyond the spawn position
CRASH_TRIM_S = 1.0  # an on-policy episode ending in a crash loses this much before it
SLOW_MPS = 1.0  # labels below this target speed count as stopping (reported per traffic level)
DRIVER_STREAM = 1  # second entropy word of the per-episode driver draws (steering noise uses the seed alone)


class UsageError(ValueError):
    """The command line asks for something that cannot work; the message says what to change."""


@dataclass(frozen=True)
class Episode:
    split: str
    town: str
    weather: str
    traffic: str
    index: int
    seed: int
    round: int = 0  # collection round: 0 expert data, 1, 2, ... on-policy rounds

    @property
    def name(self) -> str:
        name = f"{self.town}_{self.weather}_{self.traffic}_{self.index:03d}"
        return f"{name}_r{self.round}" if self.round else name


@dataclass(frozen=True)
class Driver:
    """Who drives the steps of an episode: the expert with probability `beta`, else the network."""

    checkpoint: str | None = None  # the network's checkpoint; None: the expert drives every step
    beta: float = 1.0
    digest: str = ""  # the checkpoint's content hash (deploy_files.file_digest)
    backend: str = "auto"  # DrivingModel backend / precision, as the perception node's parameters
    precision: str = "auto"

    @property
    def on_policy(self) -> bool:
        """Does the network drive any step?"""
        return self.checkpoint is not None and self.beta < 1.0

    def metadata(self) -> dict[str, str]:
        if self.checkpoint is None:
            return {bag_io.DRIVER: bag_io.EXPERT_DRIVER, bag_io.BETA: str(self.beta)}
        return {bag_io.DRIVER: self.checkpoint, bag_io.DRIVER_DIGEST: self.digest, bag_io.BETA: str(self.beta)}


EXPERT = Driver()


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


def default_scenarios(split: str) -> tuple[list[str], list[str]]:
    """Towns and weathers of a split: train/validation on the training set, test on the held-out set."""
    if split == "test":
        return list(HELDOUT_TOWNS), list(HELDOUT_WEATHERS)
    return list(TRAIN_TOWNS), list(TRAIN_WEATHERS)


def plan(split: str, towns: list[str], weathers: list[str], traffic: list[str], episodes: int,
         base_seed: int, round_index: int = 0) -> list[Episode]:
    """All episodes, ordered by town (a worker rebuilds the simulator only when the town changes).

    Round 0 keeps the names and seeds of expert collections made before rounds existed; each later round
    has its own names (`..._r1`) and seeds, so it adds episodes next to the earlier rounds' in one dataset.
    """
    planned = []
    for town in towns:
        for weather in weathers:
            for level in traffic:
                for index in range(episodes):
                    key = f"{base_seed}/{split}/{town}/{weather}/{level}/{index}"
                    key += f"/r{round_index}" if round_index else ""
                    planned.append(Episode(split, town, weather, level, index, zlib.crc32(key.encode()) % 2**31,
                                           round_index))
    return planned


def bag_path(output: Path, episode: Episode) -> Path:
    return output / episode.split / episode.name


def pending(output: Path, planned: list[Episode]) -> list[Episode]:
    """Episodes neither written nor dropped before (resume)."""
    dropped_file = output / DROPPED_LOG
    dropped = set()
    if dropped_file.exists():
        dropped = {Episode(**json.loads(line)["episode"]) for line in dropped_file.read_text().splitlines()}
    return [e for e in planned if not bag_path(output, e).exists() and e not in dropped]


def check_resume(output: Path, planned: list[Episode], driver: Driver) -> None:
    """UsageError if a bag of the plan was written with another driver or beta, or by another simulator revision
    (resuming must not mix them).

    Bags without the driver keys were written by the expert alone; bags without a revision by revision 1.
    """
    wanted = driver.digest or bag_io.EXPERT_DRIVER, float(driver.beta)
    for episode in planned:
        path = bag_path(output, episode)
        if not path.exists():
            continue
        metadata = bag_io.read_bag_metadata(path)
        revision = int(metadata.get(bag_io.SIMULATOR_REVISION, UNRECORDED_REVISION))
        if revision != SIMULATOR_REVISION:
            raise UsageError(f"{path} was collected by simulator revision {revision}, this code is revision "
                             f"{SIMULATOR_REVISION}: collect into another --output")
        found = metadata.get(bag_io.DRIVER_DIGEST, bag_io.EXPERT_DRIVER), float(metadata.get(bag_io.BETA, 1.0))
        if found != wanted:
            raise UsageError(f"{path} was driven by {metadata.get(bag_io.DRIVER, bag_io.EXPERT_DRIVER)} with beta "
                             f"{found[1]}, this run asks {driver.checkpoint or bag_io.EXPERT_DRIVER} with beta "
                             f"{driver.beta}: collect into another --round (or --output)")


# ----- routes -----
def collection_routes(routes: Sequence[RoadRoute]) -> list[RoadRoute]:
    """The catalog routes an episode may drive: at least one junction, room for the spawn on the start road,
    at most MAX_ROUTE_M from the spawn to the destination."""
    return [route for route in routes if route.junctions and route.start_road_m >= SPAWN_LONGITUDE_M + SPAWN_ROOM_M
            and route.length_m - SPAWN_LONGITUDE_M <= MAX_ROUTE_M]


def draw_route(routes: Sequence[RoadRoute], seed: int) -> RoadRoute:
    """The route of the episode with `seed` (uniform over `routes`, deterministic)."""
    if not routes:
        raise ValueError("no route to draw from")
    return routes[random.Random(seed).randrange(len(routes))]


_catalog: dict[str, list[RoadRoute]] = {}  # town -> collection_routes of its map (fixed by the town)


def episode_route(env: SimEnvironment, episode: Episode) -> RoadRoute:
    """The route `episode` drives (its town's map is loaded by a blind reset the first time)."""
    if episode.town not in _catalog:
        env.reset(episode.town, episode.weather, "empty", episode.seed, render=False)
        _catalog[episode.town] = collection_routes(env.road_routes())
    return draw_route(_catalog[episode.town], episode.seed)


def route_metadata(route: RoadRoute) -> dict[str, str]:
    return {bag_io.ROUTE_START: json.dumps(list(route.checkpoints[:2])),
            bag_io.ROUTE_DESTINATION: route.checkpoints[-1],
            bag_io.ROUTE_JUNCTIONS: ",".join(option.name for option in route.junctions),
            bag_io.ROUTE_LENGTH_M: f"{route.length_m - SPAWN_LONGITUDE_M:.1f}"}


# ----- driving -----
def load_network(driver: Driver) -> DrivingModel:
    """The driver's network on its backend (CheckpointError / BackendUnavailableError / ValueError if unusable)."""
    from msfsu_perception.inference import DrivingModel

    return DrivingModel.from_checkpoint(driver.checkpoint, backend=driver.backend, precision=driver.precision)


class Pilot:
    """Who drives each step of an episode, and the control node's controller that turns the chosen steer and
    target speed into the applied control (one speed PID, whoever asks)."""

    def __init__(self, seed: int, beta: float, network: DrivingModel | None = None) -> None:
        if beta < 1.0 and network is None:
            raise ValueError(f"beta {beta} < 1 needs a network to drive")
        self.beta, self.network = beta, network
        self.controller = ActionController()
        self._draws = np.random.default_rng((seed, DRIVER_STREAM))

    def network_drives(self) -> bool:
        """Draw who drives this step: the network with probability 1 - beta (one draw per step)."""
        return bool(self._draws.random() >= self.beta)

    def network_action(self, obs: Observation) -> Prediction:
        """The network's steer and target speed for the frame, by the perception node's per-frame function (a frame
        it rejects raises its ValueError)."""
        return infer_frame(self.network, obs.rgb, obs.depth, obs.command).prediction


def record_episode(env: SimEnvironment, episode: Episode, output: Path, max_steps: int, noise: bool,
                   driver: Driver = EXPERT, network: DrivingModel | None = None,
                   record_from: int = 0) -> EpisodeResult:
    """Drive one episode (expert, or on-policy with `network`) and write its bag (removed again if dropped).

    Steps before `record_from` are driven the same way but not written (the bag starts there, with the route).
    """
    store = bag_io.msfsu_typestore()
    build = rosbags_builder(store)
    route = episode_route(env, episode)
    expert, steering_noise = Expert(), SteeringNoise(episode.seed)
    pilot = Pilot(episode.seed, driver.beta if driver.on_policy else 1.0, network if driver.on_policy else None)
    final = bag_path(output, episode)
    partial = final.parent / PARTIAL_DIR / final.name  # same name: the .mcap file inside is named after it
    shutil.rmtree(partial, ignore_errors=True)
    partial.parent.mkdir(parents=True, exist_ok=True)
    metadata = {bag_io.SPLIT: episode.split, bag_io.MAP: episode.town, bag_io.WEATHER: episode.weather,
                bag_io.TRAFFIC: episode.traffic, bag_io.SEED: episode.seed, **route_metadata(route),
                **driver.metadata(), bag_io.ROUND: episode.round, bag_io.SIMULATOR_REVISION: SIMULATOR_REVISION}
    obs = env.reset(episode.town, episode.weather, episode.traffic, episode.seed, RouteSpec.along(route))
    trim = round(CRASH_TRIM_S / STEP_S) if driver.on_policy else 0
    held: deque[tuple[list[tuple[str, object, float]], bool, float]] = deque()  # the last `trim` steps
    noisy_steps = 0
    written: Counter[str] = Counter()
    with bag_io.mcap_writer(partial, metadata) as writer:
        connections = {topic: writer.add_connection(topic, msgtype, typestore=store)
                       for topic, msgtype in TYPES.items()}

        def write(topic: str, message: object, time_s: float) -> None:
            writer.write(connections[topic], round(time_s * 1e9), store.serialize_cdr(message, TYPES[topic]))

        def write_step(messages: list[tuple[str, object, float]], by_network: bool, label_speed: float) -> None:
            for message in messages:
                write(*message)
            written.update(frames=1, network_frames=by_network, slow_frames=label_speed < SLOW_MPS)

        while not obs.done and obs.step < max_steps:
            t = obs.time_s
            if obs.step == record_from:  # the bag's first message
                write(topics.ROUTE, build.route(t, env.route), t)
            label = expert.act_on(obs, env)
            by_network = pilot.network_drives()
            offset = steering_noise.offset(t) if noise else 0.0  # the burst schedule is the same whoever drives
            noisy = noise and steering_noise.active(t) and not by_network
            if by_network:
                prediction = pilot.network_action(obs)
                steer, target_speed = prediction.steer, prediction.target_speed
            else:
                steer, target_speed = label.steer + (offset if noisy else 0.0), label.target_speed
            control = pilot.controller.step(steer, target_speed, obs.odometry.speed, STEP_S)
            noisy_steps += noisy
            messages = [(topic, message, t) for topic, message in build.sensors(obs).items()]
            messages += [(topics.EXPERT_ACTION, build.driving_action(t, label), t),
                         (topics.VEHICLE_CONTROL, build.vehicle_control(t, control.throttle, control.steer,
                                                                        control.brake), t),
                         (topics.NOISE_INJECTION, build.flag(noisy), t),
                         (topics.NETWORK_DRIVING, build.flag(by_network), t),
                         (topics.EXPERT_LIMITED_BY, build.text(label.limited_by), t)]
            if by_network:  # what the network asked for, beside the expert's label (near misses: DrivingDataset)
                asked = ExpertAction(prediction.steer, prediction.target_speed, label.command)
                messages.append((topics.DRIVING_ACTION, build.driving_action(t, asked), t))
            if obs.step >= record_from:
                held.append((messages, by_network, label.target_speed))
            if len(held) > trim:
                write_step(*held.popleft())
            obs = env.step(control.steer, control.throttle, control.brake)
        reason = ("collision" if obs.collision else "out_of_road" if obs.out_of_road
                  else "arrived" if obs.arrived else "timeout")
        crashed = reason in bag_io.CRASH_ENDS
        if not crashed:
            while held:
                write_step(*held.popleft())
        writer.set_custom_data(bag_io.METADATA_PREFIX + bag_io.END, reason)  # metadata.yaml is written at close
    kept = (not crashed or driver.on_policy) and written["frames"] > 0
    if kept:
        partial.rename(final)
    else:
        shutil.rmtree(partial)
        written.clear()
    return EpisodeResult(episode, kept, reason, obs.step, obs.route_completion, noisy_steps, written["frames"],
                         written["network_frames"], written["slow_frames"], route.checkpoints)


# ----- worker side -----
_environment: SimEnvironment | None = None
_networks: dict[Driver, DrivingModel] = {}


def _worker_init(parent: int) -> None:
    """A pool worker dies with the parent, however the parent ends (PDEATHSIG), and only the parent takes a stop:
    the worker leaves the terminal's process group, so Ctrl-C reaches the parent alone, which then ends the pool
    (SIGTERM, on which a worker ends at once; the bag it was writing stays in .partial and is re-recorded on resume).
    In the terminal's group, each worker died of its own KeyboardInterrupt with a traceback, and a pool that lost a
    worker's job waited for it forever."""
    tie_to_parent(parent)
    os.setpgrp()
    os.environ.setdefault("OMP_NUM_THREADS", "1")


def _run(job: tuple[Episode, Path, int, bool, Driver, int, bool]) -> EpisodeResult:
    """Worker entry: one simulator (and the driver's network) per process, kept across episodes."""
    global _environment
    if _environment is None:
        _environment = SimEnvironment(SimConfig(labels=True, quality=Quality(light_meshes=job[6])))
    driver = job[4]
    network = None
    if driver.on_policy:
        if driver not in _networks:
            _networks[driver] = load_network(driver)
        network = _networks[driver]
    return record_episode(_environment, *job[:5], network=network, record_from=job[5])


def collect(output: Path, planned: list[Episode], workers: int, max_steps: int, noise: bool,
            driver: Driver = EXPERT, record_from: int = 0, light_meshes: bool = True) -> Iterator[EpisodeResult]:
    """Record the pending episodes (in `workers` processes) and yield each result as it finishes."""
    jobs = [(episode, output, max_steps, noise, driver, record_from, light_meshes)
            for episode in pending(output, planned)]
    output.mkdir(parents=True, exist_ok=True)
    if workers <= 1:
        results = map(_run, jobs)
        yield from _log_dropped(output, results)
        return
    # spawn: each worker owns one MetaDrive engine (one per process) and no inherited GL state.
    with multiprocessing.get_context("spawn").Pool(workers, initializer=_worker_init,
                                                    initargs=(os.getpid(),)) as pool:
        yield from _log_dropped(output, pool.imap_unordered(_run, jobs, chunksize=1))


def _log_dropped(output: Path, results: Iterator[EpisodeResult]) -> Iterator[EpisodeResult]:
    for result in results:
        if not result.kept:
            with (output / DROPPED_LOG).open("a") as log:
                log.write(json.dumps({"episode": asdict(result.episode), "reason": result.reason,
                                      "steps": result.steps}) + "\n")
        yield result


def summary(results: Sequence[EpisodeResult]) -> str:
    """Per traffic level: kept episodes, frames, frames labelled below SLOW_MPS (stopping), network-driven."""
    lines = ["traffic | kept episodes | frames | label < 1 m/s | driven by the network"]
    for level in sorted({r.episode.traffic for r in results}, key=list(TRAFFIC).index):
        mine = [r for r in results if r.episode.traffic == level]
        frames = sum(r.frames for r in mine)

        def share(count: int) -> str:
            return f"{count} ({100 * count / frames:.1f} %)" if frames else "0"

        lines.append(f"{level} | {sum(r.kept for r in mine)}/{len(mine)} | {frames} | "
                     f"{share(sum(r.slow_frames for r in mine))} | {share(sum(r.network_frames for r in mine))}")
    return "\n".join(lines)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="msfsu-collect", description=__doc__.splitlines()[0])
    parser.add_argument("--output", type=Path, required=True, help="dataset root; bags go to <output>/<split>/")
    parser.add_argument("--split", choices=bag_io.SPLITS, required=True)
    parser.add_argument("--episodes", type=int, default=1, help="episodes per town x weather x traffic")
    parser.add_argument("--towns", nargs="+", choices=list(TOWNS), metavar="TOWN",
                        help="default: training towns (test: held-out towns)")
    parser.add_argument("--weathers", nargs="+", choices=list(WEATHERS), metavar="WEATHER",
                        help="default: training weathers (test: held-out weathers)")
    parser.add_argument("--traffic", nargs="+", choices=list(TRAFFIC), default=["empty", "regular", "dense"])
    parser.add_argument("--max-steps", type=int, default=3000, help="episode length limit (10 steps = 1 s)")
    parser.add_argument("--record-from", type=int, default=0, metavar="STEP",
                        help="drive the first STEP steps without recording them (the bag starts at step STEP)")
    parser.add_argument("--seed", type=int, default=0, help="base seed (episode seeds derive from it)")
    parser.add_argument("--workers", type=int, default=1, help="parallel simulator processes")
    parser.add_argument("--no-noise", action="store_true", help="disable steering-noise injection")
    parser.add_argument("--full-meshes", action="store_true",
                        help="draw traffic with MetaDrive's full models instead of the light meshes (to compare)")
    parser.add_argument("--driver", type=Path, metavar="CHECKPOINT",
                        help="on-policy round (DAgger): this network drives the steps the expert does not "
                             "(default: the expert drives every step)")
    parser.add_argument("--beta", type=float,
                        help="probability that the expert drives a step (default 0 with --driver, else 1)")
    parser.add_argument("--round", type=int, default=0,
                        help="collection round: 0 expert data; on-policy rounds 1, 2, ... (own bag names and seeds)")
    parser.add_argument("--backend", default="auto", choices=["auto", "torch", "onnxruntime", "openvino"],
                        help="the driver network's backend, as the perception node's parameter")
    parser.add_argument("--precision", default="auto", choices=["auto", "fp32", "bf16", "int8"],
                        help="the driver network's precision, as the perception node's parameter")
    return parser


def driver_from_options(options: argparse.Namespace) -> Driver:
    """The episode driver the options ask for (UsageError if they cannot work)."""
    beta = options.beta if options.beta is not None else (0.0 if options.driver else 1.0)
    if not 0.0 <= beta <= 1.0:
        raise UsageError(f"--beta {beta} is not a probability in [0, 1]")
    if options.round < 0 or options.episodes < 1 or options.max_steps < 1 or options.workers < 1:
        raise UsageError("--round must be >= 0 and --episodes, --max-steps, --workers >= 1")
    if not 0 <= options.record_from < options.max_steps:
        raise UsageError(f"--record-from {options.record_from} must be in [0, --max-steps {options.max_steps})")
    if options.driver is None:
        if beta < 1.0:
            raise UsageError(f"--beta {beta} lets a network drive: name it with --driver CHECKPOINT")
        return EXPERT
    if options.round < 1:
        raise UsageError("--driver collects an on-policy round: give it --round N (N >= 1), so its bags sit "
                         "beside the expert's round 0 instead of being taken for them")
    from msfsu_perception.checkpoint import CheckpointError
    from msfsu_perception.deploy_files import file_digest
    from msfsu_perception.inference import BackendUnavailableError

    driver = Driver(str(options.driver), beta, "", options.backend, options.precision)
    try:  # load it once here: a bad checkpoint is refused before any simulator starts
        network = load_network(driver)
    except (CheckpointError, BackendUnavailableError, ValueError, OSError) as error:
        raise UsageError(f"cannot drive with {options.driver}: {str(error).splitlines()[0]}") from None
    driver = Driver(driver.checkpoint, beta, file_digest(options.driver), options.backend, options.precision)
    if driver.on_policy:
        _networks[driver] = network  # the in-process worker (--workers 1) uses it
    return driver


def main(argv: list[str] | None = None) -> int:
    options = build_parser().parse_args(argv)
    from tqdm import tqdm

    default_towns, default_weathers = default_scenarios(options.split)
    planned = plan(options.split, options.towns or default_towns, options.weathers or default_weathers,
                   options.traffic, options.episodes, options.seed, options.round)
    try:
        driver = driver_from_options(options)
        check_resume(options.output, planned, driver)
    except UsageError as error:
        print(f"msfsu-collect: {error}", file=sys.stderr)
        return 2
    interrupt_on_signals()  # SIGTERM, and SIGINT also in a background job (`kill -INT`): stop, keep what is done
    todo = len(pending(options.output, planned))
    who = "the expert"
    if driver.on_policy:
        network = _networks[driver]
        who = (f"{driver.checkpoint} on {network.backend}/{network.precision} and the expert with probability "
               f"{driver.beta}")
    print(f"{len(planned)} episodes planned (round {options.round}, driven by {who}), {len(planned) - todo} "
          "already done", file=sys.stderr)
    results = []
    try:
        with tqdm(total=todo, unit="episode") as progress:
            for result in collect(options.output, planned, options.workers, options.max_steps, not options.no_noise,
                                  driver, options.record_from, not options.full_meshes):
                results.append(result)
                progress.set_postfix_str(f"{result.episode.name}: {result.reason}")
                progress.update()
    except KeyboardInterrupt:
        print("msfsu-collect: interrupted (re-run the same command to resume)", file=sys.stderr)
        return 1
    print(f"kept {sum(r.kept for r in results)}/{todo} new episodes in {options.output}", file=sys.stderr)
    if results:
        print(summary(results), file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
