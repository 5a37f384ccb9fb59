"""The emergency brake in closed loop: the shipped network through the real node graph, in lockstep, on crossing
pedestrian scenarios of the per-ability suite. From the right: without the aeb node the car drives into the
pedestrian; with it the car stops in front of the pedestrian and reaches its goal once the road is clear. From the
left (the pedestrian crosses the other lane first and is in the corridor only when the car is too close to stop): the
brake on its corridor alone hits the pedestrian; the brake that predicts crossings stops and arrives."""

import json
import subprocess
import sys
from pathlib import Path

import pytest

REPOSITORY = Path(__file__).resolve().parents[1]
CHECKPOINT = REPOSITORY / "models" / "msfsu_default.pt"
SCENARIO = "abilities/pedestrian_right/train/01"

EPISODES = """
import json, os, sys
from pathlib import Path
from msfsu_common.ros_env import configure_ros_environment
configure_ros_environment()
from msfsu_evaluation.closed_loop.abilities import load_abilities
from msfsu_evaluation.closed_loop.episode import run_episode
from msfsu_evaluation.closed_loop.graph_agent import GraphAgent
from msfsu_sim.environment import SimConfig, SimEnvironment

route = {r.key: r for r in load_abilities()[1]}[sys.argv[2]]
env = SimEnvironment(SimConfig(labels=False))
for aeb, crossing in json.loads(sys.argv[4]):
    agent = GraphAgent("msfsu_aeb" if aeb else "msfsu", Path(sys.argv[1]), env, Path(sys.argv[3]), aeb=aeb,
                       aeb_crossing=crossing)
    try:
        result, output = run_episode(env, route, agent, expert_labels=False)
    finally:
        agent.close()
    telemetry = output.telemetry.arrays()
    from msfsu_evaluation.closed_loop.telemetry import NAMES
    distance = telemetry[:, NAMES.index("pedestrian_distance_m")]
    decision = telemetry[:, NAMES.index("aeb_decision")]
    print(json.dumps({"aeb": aeb, "status": result.status, "collision_type": result.collision_type,
                      "actor": result.collision_actor,
                      "brakes": None if result.aeb is None else result.aeb.brakes,
                      "false_brakes": None if result.aeb is None else result.aeb.false_brakes,
                      "caps": None if result.aeb is None else result.aeb.caps,
                      "false_caps": None if result.aeb is None else result.aeb.false_caps,
                      "braked_steps": int((decision == 2).sum()),
                      "closest_m": float(min(d for d in distance if d == d)) if (distance == distance).any() else None}),
          flush=True)
env.close()
"""


def episodes(tmp_path: Path, scenario: str, graphs: list[tuple[bool, bool]]) -> list[dict]:
    """One episode of `scenario` per (aeb, aeb_crossing) graph, in order: each one's outcome."""
    run = subprocess.run([sys.executable, "-c", EPISODES, str(CHECKPOINT), scenario, str(tmp_path / "graph.log"),
                          json.dumps(graphs)], capture_output=True, text=True, timeout=900)
    assert run.returncode == 0, run.stderr[-3000:]
    return [json.loads(line) for line in run.stdout.splitlines()[-len(graphs):]]


@pytest.mark.slow  # two graph start-ups and two episodes of the shipped network: about 2 min on 2 cores
def test_without_the_brake_the_car_hits_the_crossing_pedestrian_with_it_the_car_stops_and_arrives(tmp_path):
    without, with_aeb = episodes(tmp_path, SCENARIO, [(False, False), (True, False)])
    assert (without["status"], without["collision_type"], without["actor"]) == (
        "collision", "pedestrian", "pedestrian crossing from the right")
    assert without["brakes"] is None  # no brake in that graph
    assert with_aeb["status"] == "success" and with_aeb["brakes"] >= 1 and with_aeb["false_brakes"] == 0
    assert with_aeb["braked_steps"] > 0 and with_aeb["closest_m"] > 2.3  # stopped with the pedestrian ahead of it


@pytest.mark.slow  # two graph start-ups and two episodes of the shipped network: about 2 min on 2 cores
def test_a_pedestrian_from_the_left_is_hit_by_the_corridor_brake_and_waited_for_by_the_one_predicting_crossings(
        tmp_path):
    corridor, crossing = episodes(tmp_path, "abilities/pedestrian_left/train/00", [(True, False), (True, True)])
    assert (corridor["status"], corridor["collision_type"]) == ("collision", "pedestrian")
    assert crossing["status"] == "success" and crossing["false_brakes"] == 0
    assert crossing["caps"] >= 1 and crossing["false_caps"] == 0  # it capped for the pedestrian, not for nothing
    assert crossing["closest_m"] > 2.3  # it waited with the pedestrian ahead of it
