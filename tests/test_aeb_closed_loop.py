"""The emergency brake in closed loop: the shipped network through the real node graph, in lockstep, on one crossing
pedestrian scenario of the per-ability suite, without and with the aeb node. Without it the car drives into the
pedestrian; with it the car stops in front of the pedestrian and reaches its goal once the road is clear."""

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
for aeb in (False, True):
    agent = GraphAgent("msfsu_aeb" if aeb else "msfsu", Path(sys.argv[1]), env, Path(sys.argv[3]), aeb=aeb)
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
                      "braked_steps": int((decision == 2).sum()),
                      "closest_m": float(min(d for d in distance if d == d)) if (distance == distance).any() else None}),
          flush=True)
env.close()
"""


@pytest.mark.slow  # two graph start-ups and two episodes of the shipped network: about 2 min on 2 cores
def test_without_the_brake_the_car_hits_the_crossing_pedestrian_with_it_the_car_stops_and_arrives(tmp_path):
    run = subprocess.run([sys.executable, "-c", EPISODES, str(CHECKPOINT), SCENARIO, str(tmp_path / "graph.log")],
                         capture_output=True, text=True, timeout=900)
    assert run.returncode == 0, run.stderr[-3000:]
    without, with_aeb = (json.loads(line) for line in run.stdout.splitlines()[-2:])
    assert (without["status"], without["collision_type"], without["actor"]) == (
        "collision", "pedestrian", "pedestrian crossing from the right")
    assert without["brakes"] is None  # no brake in that graph
    assert with_aeb["status"] == "success" and with_aeb["brakes"] >= 1 and with_aeb["false_brakes"] == 0
    assert with_aeb["braked_steps"] > 0 and with_aeb["closest_m"] > 2.3  # stopped with the pedestrian ahead of it
