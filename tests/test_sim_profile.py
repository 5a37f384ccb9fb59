"""`python -m msfsu_bringup sim_expert`: the simulator, in lockstep with the control node, drives a car."""

import math
import signal
import subprocess
import sys

from nav_msgs.msg import Odometry

from msfsu_common import topics
from msfsu_interfaces.msg import VehicleControl

DRIVEN_M = 15.0


def distance(a: Odometry, b: Odometry) -> float:
    return math.hypot(b.pose.pose.position.x - a.pose.pose.position.x, b.pose.pose.position.y - a.pose.pose.position.y)


def test_sim_expert_profile_drives_the_car_through_the_control_node(graph):
    odometry = graph.probe.collect(Odometry, topics.ODOMETRY)
    controls = graph.probe.collect(VehicleControl, topics.VEHICLE_CONTROL)
    launch = subprocess.Popen([sys.executable, "-m", "msfsu_bringup", "sim_expert", "--arg", "traffic=empty"],
                              stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        driven = graph.wait_for(lambda: len(odometry) > 1 and distance(odometry[0], odometry[-1]) > DRIVEN_M, 150.0)
    finally:
        launch.send_signal(signal.SIGINT)
        output, _ = launch.communicate(timeout=60)
    assert driven, output[-3000:]
    assert launch.returncode == 0, output[-3000:]
    # lockstep: every frame the car moved on was answered by a control stamped with that frame's time
    frame_stamps = {(o.header.stamp.sec, o.header.stamp.nanosec) for o in odometry[:-1]}
    control_stamps = {(c.header.stamp.sec, c.header.stamp.nanosec) for c in controls}
    assert len(frame_stamps - control_stamps) <= 1
