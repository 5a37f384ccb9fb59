"""The per-ability suite: its committed scenario file, its scenarios in the simulator, its page."""

import json
import subprocess
import sys

import pytest

from msfsu_evaluation.closed_loop.abilities import (ABILITIES, ABILITIES_FILE, ROUTES_PER_ABILITY, choose_abilities,
                                                    load_abilities)
from msfsu_evaluation.closed_loop.ability_report import BOTH, CONFLICTS, ability_markdown, ability_tables
from msfsu_evaluation.closed_loop.episode import STAGES
from msfsu_evaluation.closed_loop.episode_record import EpisodeResult
from msfsu_evaluation.closed_loop.runs import Record


def test_the_scenario_file_holds_every_ability_in_both_conditions_and_is_what_its_generator_makes(tmp_path):
    _, routes = load_abilities()
    for ability in ABILITIES:
        for condition in ("train", "heldout"):
            chosen = choose_abilities(routes, [condition], [ability])
            assert [route.index for route in chosen] == list(range(ROUTES_PER_ABILITY))
            assert {route.scenario.kind for route in chosen} == {ABILITIES[ability].kind}
            assert all(route.scenario.goal_m - route.longitude_m == pytest.approx(route.length_m, abs=0.11)
                       for route in chosen)
    assert len({route.seed for route in routes}) == len(routes)
    out = tmp_path / "abilities.json"
    run = subprocess.run([sys.executable, "-m", "msfsu_evaluation.closed_loop.make_abilities", "--out", str(out)],
                         capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr[-2000:]
    assert out.read_text() == ABILITIES_FILE.read_text()


SCENARIOS = """
import json, sys
from msfsu_evaluation.closed_loop.abilities import load_abilities
from msfsu_evaluation.closed_loop.episode import ExpertDriver, run_episode
from msfsu_sim.environment import SimConfig, SimEnvironment

class Ignoring(ExpertDriver):
    '''The expert's steering and speed as if the road were empty: it sees none of the actors.'''
    name = "ignoring"
    def act(self, obs, env):
        self.action = self.expert.act(obs.odometry, env.tracker, obs.command, [], 0.1)
        control = self.expert.speed_controller.step(self.action.target_speed, obs.odometry.speed)
        return self.action.steer, control.throttle, control.brake

routes = {route.key: route for route in load_abilities()[1]}
env = SimEnvironment(SimConfig(labels=False))
def drive(key, driver):
    result, output = run_episode(env, routes[key], driver)
    timing = [result.wall_s, result.timing.wall_s, result.timing.cpu_s]  # not repeatable: kept apart
    return [result.status, result.collision_type, result.collision_actor, output.trajectory.tolist(),
            output.telemetry.arrays().tolist(), timing]
for key in sys.argv[1:]:
    for driver in (ExpertDriver, Ignoring):
        print(json.dumps([key, driver.name, *drive(key, driver())]), flush=True)
print(json.dumps([sys.argv[1], "again", *drive(sys.argv[1], Ignoring())]), flush=True)
"""
HIT = {"pedestrian_left": ("pedestrian", "pedestrian crossing from the left"),
       "pedestrian_right": ("pedestrian", "pedestrian crossing from the right"),
       "pedestrian_occluded": ("pedestrian", "pedestrian stepping out behind a parked car"),
       "lead_braking": ("vehicle", "lead car braking hard"), "cut_in": ("vehicle", "car cutting in"),
       "crossing_traffic": ("vehicle", "car crossing with the right of way")}


def test_the_expert_solves_each_ability_a_driver_blind_to_the_actor_hits_it_and_a_scenario_repeats_exactly():
    """One scenario per ability (train, index 0: all in town_a), blind (no rendering): the expert reaches the goal;
    the expert's own driving with the actors hidden from it collides with the actor the record names, but on the clear
    road; the first scenario driven again after the others repeats exactly (placement, motion and telemetry)."""
    keys = [f"abilities/{ability}/train/00" for ability in ("pedestrian_occluded", *HIT.keys() - {"pedestrian_occluded"},
                                                            "clear_road")]
    run = subprocess.run([sys.executable, "-c", SCENARIOS, *keys], capture_output=True, text=True, timeout=600)
    assert run.returncode == 0, run.stderr[-3000:]
    episodes = {(key, driver): rest[:-1] for key, driver, *rest in map(json.loads, run.stdout.splitlines())}
    timings = [json.loads(line)[-1] for line in run.stdout.splitlines()]
    for wall_s, stages, cpu in timings:  # where each episode's time went (EpisodeTiming): the stages cover its wall time
        assert set(stages) <= set(STAGES) and {"reset", "simulate", "driver", "judge"} <= set(stages)
        assert sum(stages.values()) == pytest.approx(wall_s, abs=0.1) and cpu["worker"] > 0
    for key in keys:
        ability = key.split("/")[1]
        status, kind, actor, *_ = episodes[(key, "expert")]
        assert (status, kind, actor) == ("success", "", ""), key
        status, kind, actor, *_ = episodes[(key, "ignoring")]
        assert (status, kind, actor) == (("collision", *HIT[ability]) if ability in HIT else ("success", "", "")), key
    assert episodes[(keys[0], "again")] == episodes[(keys[0], "ignoring")]


def _record(agent: str, ability: str, condition: str, index: int, success: bool) -> Record:
    route = f"abilities/{ability}/{condition}/{index:02d}"
    episode = EpisodeResult(agent, route, "success" if success else "collision", success, 8.0 if success else 4.0, 80,
                            1.0 if success else 0.5, "" if success else "pedestrian", 0.0, 30.0, 4.0, 0,
                            collision_actor="" if success else "pedestrian crossing from the left")
    return Record(None, episode)


def test_the_page_gives_each_ability_and_the_pooled_conflicts_and_pairs_the_agents_on_the_same_scenarios():
    _, routes = load_abilities()
    chosen = [route for route in routes if route.task in ("pedestrian_left", "clear_road") and route.index < 4]
    records = {}
    for route in chosen:
        ability, condition, index = route.task, route.condition, route.index
        for agent, success in (("expert", True), ("msfsu", ability == "clear_road" or index == 0)):
            record = _record(agent, ability, condition, index, success)
            records[record.key] = record
    cells, paired = ability_tables(records, chosen, ["expert", "msfsu"], ["train", "heldout"])
    by_key = {(c.agent, c.ability, c.condition): c for c in cells}
    left = by_key[("msfsu", "pedestrian_left", BOTH)]
    assert (left.scenarios, left.successes, left.collisions) == (8, 2, {"pedestrian": 6})
    assert by_key[("msfsu", CONFLICTS, BOTH)].scenarios == 8  # the clear road, the control, is not pooled in
    assert by_key[("msfsu", "clear_road", "train")].mean_time_to_goal_s == 8.0
    row = next(r for r in paired if r.suite == "pedestrian_left" and r.condition == BOTH)
    assert (row.a, row.b, row.only_a, row.only_b, row.routes) == ("expert", "msfsu", 6, 0, 8)
    page = ability_markdown(cells, paired, ["expert", "msfsu"], ["train", "heldout"], {}, {}, 0)
    assert "| pedestrian_left (pedestrian crossing from the left) | train | 100 (51-100); 8.0 s | " \
           "25 (5-70); hit 3 pedestrian; 8.0 s |" in page
    assert "| expert vs msfsu | pedestrian_left | all | 8 | 8 | 2 | 6 | 0 |" in page
