"""A network's telemetry rows are what its perception node published: one scenario through the real node graph
(GraphAgent: route, perception, control as processes) in lockstep, with a second, independent listener on
/msfsu/driving_action; every row's action must be the message stamped with that row's frame."""

import json
import subprocess
import sys

import numpy as np

EPISODE = """
import json, os, sys, threading
from pathlib import Path
from msfsu_common.ros_env import configure_ros_environment
configure_ros_environment()
import rclpy
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from msfsu_common import topics
from msfsu_interfaces.msg import DrivingAction
from msfsu_evaluation.closed_loop.abilities import load_abilities
from msfsu_evaluation.closed_loop.episode import run_episode
from msfsu_evaluation.closed_loop.graph_agent import GraphAgent
from msfsu_evaluation.closed_loop.telemetry import NAMES
from msfsu_sim.environment import SimConfig, SimEnvironment

context = Context()
rclpy.init(context=context, domain_id=int(os.environ["ROS_DOMAIN_ID"]))
listener = Node("independent_listener", context=context)
heard = {}
def on_action(msg):
    heard[msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec] = [msg.steer, msg.target_speed, msg.command]
listener.create_subscription(DrivingAction, topics.DRIVING_ACTION, on_action, 100)
executor = SingleThreadedExecutor(context=context)
executor.add_node(listener)
threading.Thread(target=executor.spin, daemon=True).start()
route = {r.key: r for r in load_abilities()[1]}["abilities/clear_road/train/00"]
env = SimEnvironment(SimConfig(labels=False))
agent = GraphAgent("tiny", Path(sys.argv[1]), env, Path(sys.argv[2]))
try:
    result, output = run_episode(env, route, agent, blocked_s=3.0, expert_labels=False)
finally:
    agent.close()
    env.close()
rows = output.telemetry.arrays()
columns = [NAMES.index(name) for name in ("time_s", "action_steer", "action_target_speed_mps", "action_command",
                                          "action_age_steps", "expert_steer")]
print(json.dumps({"rows": rows[:, columns].tolist(), "heard": {str(k): v for k, v in heard.items()},
                  "status": result.status}))
executor.shutdown()
rclpy.try_shutdown(context=context)
"""


def test_every_telemetry_row_holds_the_action_the_perception_node_published_for_its_frame(tmp_path, tiny_checkpoint):
    run = subprocess.run([sys.executable, "-c", EPISODE, str(tiny_checkpoint), str(tmp_path / "graph.log")],
                         capture_output=True, text=True, timeout=600)
    assert run.returncode == 0, run.stderr[-3000:] + (tmp_path / "graph.log").read_text()[-2000:]
    data = json.loads(run.stdout.splitlines()[-1])
    rows, heard = np.array(data["rows"]), {int(k): v for k, v in data["heard"].items()}
    assert len(rows) >= 10
    for time_s, steer, target, command, age, expert_steer in rows:
        published = heard[round(time_s * 1e9)]  # the frame's own action: lockstep answers every frame
        assert age == 0 and np.isnan(expert_steer)  # expert labels off
        assert abs(steer - published[0]) <= 0.5e-4 + 1e-6 and abs(target - published[1]) <= 0.005 + 1e-6
        assert command == published[2]
    assert np.ptp(rows[:, 1]) > 1e-3  # the random network's steer changes with what it sees: the match means something
