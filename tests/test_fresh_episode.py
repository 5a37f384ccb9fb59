"""Every benchmark episode starts the graph fresh: the same scenario driven first and again after another one, through
one running node graph (GraphAgent: route, perception, control as processes) in lockstep, gives the same steps,
trajectory and actions. Before each episode the agent calls every node's ~/reset (msfsu_common.reset); without it the
control's PID and steer limiter, which the episode before left moving, drove the scenario differently."""

import json
import subprocess
import sys
from pathlib import Path

import pytest

EPISODES = """
import json, sys
from pathlib import Path
from msfsu_common.ros_env import configure_ros_environment
configure_ros_environment()
from msfsu_evaluation.closed_loop.abilities import load_abilities
from msfsu_evaluation.closed_loop.episode import run_episode
from msfsu_evaluation.closed_loop.graph_agent import GraphAgent
from msfsu_sim.environment import SimConfig, SimEnvironment

routes = {r.key: r for r in load_abilities()[1]}
env = SimEnvironment(SimConfig(labels=False))
agent = GraphAgent("tiny", Path(sys.argv[1]), env, Path(sys.argv[2]))
try:
    for key in sys.argv[3:]:
        result, output = run_episode(env, routes[key], agent, blocked_s=3.0, expert_labels=False)
        print(json.dumps({"key": key, "status": result.status, "steps": result.steps,
                          "trajectory": output.trajectory.tolist(), "telemetry": output.telemetry.arrays().tolist(),
                          "unanswered": result.unanswered_frames, "reset_s": result.timing.wall_s["reset graph"]}),
              flush=True)
finally:
    agent.close()
    env.close()
"""


@pytest.fixture(scope="module")
def driving_checkpoint(tmp_path_factory) -> Path:
    """A random MSFSU (ResNet-18 V2, 64x64) whose branches ask for about 6 m/s: it drives, so the speed PID works
    between full throttle and full brake, where its state shows (a random network's ~0 m/s only ever brakes)."""
    import torch

    from msfsu_perception.checkpoint import save_checkpoint
    from msfsu_perception.model import MSFSUConfig, build_model
    from msfsu_perception.preprocessing import PreprocessConfig

    torch.manual_seed(0)
    model = build_model(MSFSUConfig(backbone="resnet18v2", input_height=64, input_width=64))
    with torch.no_grad():
        for branch in model.policy.branches:
            branch[-1].bias[1] = 0.6  # speed / speed_scale (10 m/s)
    path = tmp_path_factory.mktemp("checkpoints") / "driving.pt"
    save_checkpoint(path, model, PreprocessConfig(input_height=64, input_width=64))
    return path


def test_an_episode_gives_the_same_steps_whatever_the_graph_drove_before_it(tmp_path, driving_checkpoint):
    first, other = "abilities/clear_road/train/00", "abilities/cut_in/train/00"
    run = subprocess.run([sys.executable, "-c", EPISODES, str(driving_checkpoint), str(tmp_path / "graph.log"),
                          first, other, first], capture_output=True, text=True, timeout=600)
    assert run.returncode == 0, run.stderr[-3000:] + (tmp_path / "graph.log").read_text()[-2000:]
    fresh, between, again = (json.loads(line) for line in run.stdout.splitlines()[-3:])
    assert (fresh["key"], between["key"], again["key"]) == (first, other, first)
    assert fresh["unanswered"] == again["unanswered"] == 0 and fresh["steps"] >= 10
    assert between["trajectory"] != fresh["trajectory"]  # another episode, which leaves the controller moving
    for field in ("status", "steps", "trajectory", "telemetry"):  # actions, controls and poses, step by step
        assert again[field] == fresh[field], field
    assert 0 < again["reset_s"] < 1.0  # every node answered its reset
