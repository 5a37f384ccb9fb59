"""The episodes of a collection and where their bags go.

Episodes are planned from (split, towns, weathers, traffic levels, N, round), each with a seed derived from the
base seed, its name and its round, so a run is deterministic and can resume: finished bags (`bag_path`) and
dropped episodes (DROPPED_LOG) are skipped, and bags are written under `<split>/.partial/` and renamed only when
complete.
"""

from __future__ import annotations

import json
import zlib
from dataclasses import dataclass
from pathlib import Path

from msfsu_common import bag_io
from msfsu_sim import SIMULATOR_REVISION, UNRECORDED_REVISION
from msfsu_sim.episode_driver import Driver
from msfsu_sim.scenarios import HELDOUT_TOWNS, HELDOUT_WEATHERS, TRAIN_TOWNS, TRAIN_WEATHERS

DROPPED_LOG = "dropped.jsonl"
PARTIAL_DIR = ".partial"


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


def partial_bag_path(output: Path, episode: Episode) -> Path:
    """Where the episode's bag is written until it is complete (same name: the .mcap file inside is named after it)."""
    final = bag_path(output, episode)
    return final.parent / PARTIAL_DIR / final.name


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
