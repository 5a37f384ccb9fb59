"""`msfsu-collect`: expert driving episodes -> one rosbag2 MCAP bag per episode (paper III-A).

Episodes are planned from (split, towns, weathers, traffic levels, N), each with a seed derived from
the base seed and its name, so a run is deterministic and can resume: finished bags are skipped and
bags are written under `<split>/.partial/` and renamed only when complete. Episodes that end in a
collision or off the road are dropped (listed in `dropped.jsonl`), as the paper keeps only clean driving.

Routes: each episode drives a route drawn (by its seed) from its town's start/destination pairs
(`msfsu_sim.route_catalog`, the catalog the benchmark's routes come from) that cross at least one junction,
leave room for the spawn on the start road and are at most MAX_ROUTE_M long. The bag's metadata names the
route (start road, destination, junction options, length).
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
from collections.abc import Iterator, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path

from msfsu_common import bag_io, topics
from msfsu_sim.environment import SPAWN_LONGITUDE_M, RouteSpec, SimConfig, SimEnvironment
from msfsu_sim.expert import Expert, SteeringNoise
from msfsu_sim.messages import TYPES, rosbags_builder
from msfsu_sim.route_catalog import RoadRoute
from msfsu_sim.scenarios import HELDOUT_TOWNS, HELDOUT_WEATHERS, TRAFFIC, TRAIN_TOWNS, TRAIN_WEATHERS

DROPPED_LOG = "dropped.jsonl"
PARTIAL_DIR = ".partial"
MAX_ROUTE_M = 350.0  # from the spawn to the destination: a few minutes of driving (the benchmark's limit)
SPAWN_ROOM_M = 5.0  # the start road must reach this far beyond the spawn position


@dataclass(frozen=True)
class Episode:
    split: str
    town: str
    weather: str
    traffic: str
    index: int
    seed: int

    @property
    def name(self) -> str:
        return f"{self.town}_{self.weather}_{self.traffic}_{self.index:03d}"


@dataclass(frozen=True)
class EpisodeResult:
    episode: Episode
    kept: bool
    reason: str  # arrived / timeout / collision / out_of_road
    steps: int
    route_completion: float
    noisy_steps: int
    route: tuple[str, ...] = ()  # checkpoints of the route driven


def default_scenarios(split: str) -> tuple[list[str], list[str]]:
    """Towns and weathers of a split: train/validation on the training set, test on the held-out set."""
    if split == "test":
        return list(HELDOUT_TOWNS), list(HELDOUT_WEATHERS)
    return list(TRAIN_TOWNS), list(TRAIN_WEATHERS)


def plan(split: str, towns: list[str], weathers: list[str], traffic: list[str], episodes: int,
         base_seed: int) -> list[Episode]:
    """All episodes, ordered by town (a worker rebuilds the simulator only when the town changes)."""
    planned = []
    for town in towns:
        for weather in weathers:
            for level in traffic:
                for index in range(episodes):
                    key = f"{base_seed}/{split}/{town}/{weather}/{level}/{index}"
                    planned.append(Episode(split, town, weather, level, index, zlib.crc32(key.encode()) % 2**31))
    return planned


def bag_path(output: Path, episode: Episode) -> Path:
    return output / episode.split / episode.name


def pending(output: Path, planned: list[Episode]) -> list[Episode]:
    """Episodes neither written nor dropped before (resume)."""
    dropped_file = output / DROPPED_LOG
    dropped = set()
    if dropped_file.exists():
        dropped = {tuple(json.loads(line)["episode"].values()) for line in dropped_file.read_text().splitlines()}
    return [e for e in planned if not bag_path(output, e).exists() and tuple(asdict(e).values()) not in dropped]


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


# ----- worker side -----
_environment: SimEnvironment | None = None


def _worker_init() -> None:
    os.environ.setdefault("OMP_NUM_THREADS", "1")


def record_episode(env: SimEnvironment, episode: Episode, output: Path, max_steps: int,
                   noise: bool) -> EpisodeResult:
    """Drive one episode with the expert and write its bag (removed again if the episode is dropped)."""
    store = bag_io.msfsu_typestore()
    build = rosbags_builder(store)
    route = episode_route(env, episode)
    expert, steering_noise = Expert(), SteeringNoise(episode.seed)
    final = bag_path(output, episode)
    partial = final.parent / PARTIAL_DIR / final.name  # same name: the .mcap file inside is named after it
    shutil.rmtree(partial, ignore_errors=True)
    partial.parent.mkdir(parents=True, exist_ok=True)
    metadata = {bag_io.SPLIT: episode.split, bag_io.MAP: episode.town, bag_io.WEATHER: episode.weather,
                bag_io.TRAFFIC: episode.traffic, bag_io.SEED: episode.seed, **route_metadata(route)}
    obs = env.reset(episode.town, episode.weather, episode.traffic, episode.seed, RouteSpec.along(route))
    noisy_steps = 0
    with bag_io.mcap_writer(partial, metadata) as writer:
        connections = {topic: writer.add_connection(topic, msgtype, typestore=store)
                       for topic, msgtype in TYPES.items()}

        def write(topic: str, message: object, time_s: float) -> None:
            writer.write(connections[topic], round(time_s * 1e9),
                         store.serialize_cdr(message, TYPES[topic]))

        write(topics.ROUTE, build.route(obs.time_s, env.route), obs.time_s)
        while not obs.done and obs.step < max_steps:
            t = obs.time_s
            action, longitudinal = expert.drive(obs, env)
            noisy = noise and steering_noise.active(t)
            applied_steer = max(-1.0, min(1.0, action.steer + (steering_noise.offset(t) if noise else 0.0)))
            noisy_steps += noisy
            for topic, message in build.sensors(obs).items():
                write(topic, message, t)
            write(topics.EXPERT_ACTION, build.driving_action(t, action), t)
            write(topics.VEHICLE_CONTROL,
                  build.vehicle_control(t, longitudinal.throttle, applied_steer, longitudinal.brake), t)
            write(topics.NOISE_INJECTION, build.flag(noisy), t)
            obs = env.step(applied_steer, longitudinal.throttle, longitudinal.brake)
    reason = ("collision" if obs.collision else "out_of_road" if obs.out_of_road
              else "arrived" if obs.arrived else "timeout")
    kept = reason in ("arrived", "timeout")
    if kept:
        partial.rename(final)
    else:
        shutil.rmtree(partial)
    return EpisodeResult(episode, kept, reason, obs.step, obs.route_completion, noisy_steps, route.checkpoints)


def _run(job: tuple[Episode, Path, int, bool]) -> EpisodeResult:
    """Worker entry: one simulator per process, kept across episodes."""
    global _environment
    if _environment is None:
        _environment = SimEnvironment(SimConfig(labels=True))
    return record_episode(_environment, *job)


def collect(output: Path, planned: list[Episode], workers: int, max_steps: int,
            noise: bool) -> Iterator[EpisodeResult]:
    """Record the pending episodes (in `workers` processes) and yield each result as it finishes."""
    jobs = [(episode, output, max_steps, noise) for episode in pending(output, planned)]
    output.mkdir(parents=True, exist_ok=True)
    if workers <= 1:
        results = map(_run, jobs)
        yield from _log_dropped(output, results)
        return
    # spawn: each worker owns one MetaDrive engine (one per process) and no inherited GL state.
    with multiprocessing.get_context("spawn").Pool(workers, initializer=_worker_init) as pool:
        yield from _log_dropped(output, pool.imap_unordered(_run, jobs, chunksize=1))


def _log_dropped(output: Path, results: Iterator[EpisodeResult]) -> Iterator[EpisodeResult]:
    for result in results:
        if not result.kept:
            with (output / DROPPED_LOG).open("a") as log:
                log.write(json.dumps({"episode": asdict(result.episode), "reason": result.reason,
                                      "steps": result.steps}) + "\n")
        yield result


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="msfsu-collect", description=__doc__.splitlines()[0])
    parser.add_argument("--output", type=Path, required=True, help="dataset root; bags go to <output>/<split>/")
    parser.add_argument("--split", choices=bag_io.SPLITS, required=True)
    parser.add_argument("--episodes", type=int, default=1, help="episodes per town x weather x traffic")
    parser.add_argument("--towns", nargs="+", help="default: training towns (test: held-out towns)")
    parser.add_argument("--weathers", nargs="+", help="default: training weathers (test: held-out weathers)")
    parser.add_argument("--traffic", nargs="+", choices=list(TRAFFIC), default=["empty", "regular", "dense"])
    parser.add_argument("--max-steps", type=int, default=3000, help="episode length limit (10 steps = 1 s)")
    parser.add_argument("--seed", type=int, default=0, help="base seed (episode seeds derive from it)")
    parser.add_argument("--workers", type=int, default=1, help="parallel simulator processes")
    parser.add_argument("--no-noise", action="store_true", help="disable steering-noise injection")
    args = parser.parse_args(argv)

    from tqdm import tqdm

    default_towns, default_weathers = default_scenarios(args.split)
    planned = plan(args.split, args.towns or default_towns, args.weathers or default_weathers, args.traffic,
                   args.episodes, args.seed)
    todo = len(pending(args.output, planned))
    print(f"{len(planned)} episodes planned, {len(planned) - todo} already done", file=sys.stderr)
    kept = 0
    with tqdm(total=todo, unit="episode") as progress:
        for result in collect(args.output, planned, args.workers, args.max_steps, not args.no_noise):
            kept += result.kept
            progress.set_postfix_str(f"{result.episode.name}: {result.reason}")
            progress.update()
    print(f"kept {kept}/{todo} new episodes in {args.output}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
