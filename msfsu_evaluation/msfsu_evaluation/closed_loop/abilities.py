"""The per-ability scenario suite (`msfsu-benchmark --suite abilities`): short scripted conflicts, one ability each.

Bench2Drive reports a success rate per ability (emergency brake, give way, merging, ...) beside the driving score;
this suite does the same on the embedded simulator, in minutes instead of the hour the 350 routes take. Each
scenario is a route of the benchmark's kind (a town, a weather, a start and a destination) with one scripted actor
(msfsu_sim.scripted) and a goal a few tens of metres past the conflict: the episode succeeds when the car reaches the
goal without a collision, within the ability timeout. No other traffic: what fails is the ability, nothing else.

The scenarios live in `abilities.json` next to this module, generated once from the towns' maps with

    python -m msfsu_evaluation.closed_loop.make_abilities

and committed, as routes.json is; its `version` is recorded with every run. Per ability and condition
ROUTES_PER_ABILITY scenarios, spread round-robin over the condition's towns and weathers, each with its own place on
the map and its own actor parameters (seeded). `clear_road` drives the places of the mid-block abilities with nobody
there: a car that stops on it stops for nothing.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from msfsu_evaluation.closed_loop.suites import TASKS, BenchmarkRoute, Task, first_per_task
from msfsu_sim.scenario_spec import (CLEAR_ROAD, CROSSING_TRAFFIC, CUT_IN, LEAD_BRAKING, PEDESTRIAN_BEHIND_PARKED_CAR,
                                     PEDESTRIAN_CROSSING)

SUITE = "abilities"
ABILITIES_FILE = Path(__file__).with_name("abilities.json")
ABILITIES_VERSION = 1
ROUTES_PER_ABILITY = 16  # per condition: 16 of 16 has a Wilson 95 % interval of 81-100 %, 14 of 16 of 64-96 %
# Timeout: the route at 10 km/h plus a margin for the wait (a crossing takes the pedestrian about 12 s)
ABILITY_TASK = Task(SUITE, "scenario", "empty", 10.0, 15.0)


@dataclass(frozen=True)
class Ability:
    name: str  # the route's task key
    kind: str  # msfsu_sim.scenario_spec kind
    side: str  # the kerb a crossing pedestrian starts from ("" for the others)
    title: str
    bench2drive: str  # the Bench2Drive ability it stands for


ABILITIES: dict[str, Ability] = {ability.name: ability for ability in (
    Ability("pedestrian_left", PEDESTRIAN_CROSSING, "left", "pedestrian crossing from the left", "emergency brake"),
    Ability("pedestrian_right", PEDESTRIAN_CROSSING, "right", "pedestrian crossing from the right", "emergency brake"),
    Ability("pedestrian_occluded", PEDESTRIAN_BEHIND_PARKED_CAR, "",
            "pedestrian stepping out in front of a parked car", "emergency brake"),
    Ability("lead_braking", LEAD_BRAKING, "", "lead vehicle braking hard", "emergency brake"),
    Ability("cut_in", CUT_IN, "", "vehicle cutting in from the next lane", "merging"),
    Ability("crossing_traffic", CROSSING_TRAFFIC, "", "junction: crossing traffic has the right of way", "give way"),
    Ability("clear_road", CLEAR_ROAD, "", "clear road of the same shape (control: no reason to stop)", "-"),
)}


def route_task(route: BenchmarkRoute) -> Task:
    """The task whose traffic and timeout a route is driven with: its suite task, or the ability task."""
    return ABILITY_TASK if route.scenario is not None else TASKS[route.task]


def load_abilities(path: Path = ABILITIES_FILE) -> tuple[int, list[BenchmarkRoute]]:
    """(version, scenario routes); ValueError if the file is not an abilities file of this version."""
    data = json.loads(Path(path).read_text())
    if data.get("suite") != SUITE or data.get("version") != ABILITIES_VERSION:
        raise ValueError(f"{path}: not an abilities file of version {ABILITIES_VERSION} (suite {data.get('suite')!r}, "
                         f"version {data.get('version')!r}; regenerate: python -m "
                         "msfsu_evaluation.closed_loop.make_abilities)")
    routes = []
    for item in data["routes"]:
        route = BenchmarkRoute.from_dict(item)
        if route.task not in ABILITIES or route.scenario is None or route.scenario.kind != ABILITIES[route.task].kind:
            raise ValueError(f"{path}: {route.key} is no scenario of a known ability")
        routes.append(route)
    return data["version"], routes


def choose_abilities(routes: Sequence[BenchmarkRoute], conditions: Sequence[str], abilities: Sequence[str] | None = None,
                     per_ability: int | None = None, towns: Sequence[str] | None = None) -> list[BenchmarkRoute]:
    """The scenarios of the given conditions (and abilities, and towns), the first `per_ability` of each (in index
    order, among those of the towns)."""
    return first_per_task([route for route in routes if route.condition in conditions
                           and (not abilities or route.task in abilities) and (not towns or route.town in towns)],
                          per_ability)