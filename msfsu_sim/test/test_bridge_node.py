"""The bridge in lockstep with a scripted controller, both spun in-process on a fresh context.

Spun on the main thread: Panda3D's task manager installs a signal handler when it steps.
"""

import time

import pytest

rclpy = pytest.importorskip("rclpy")
from rclpy.context import Context  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.node import Node  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402
from rclpy.qos import QoSProfile, ReliabilityPolicy  # noqa: E402
from rosgraph_msgs.msg import Clock  # noqa: E402
from sensor_msgs.msg import Image  # noqa: E402

from msfsu_common import topics  # noqa: E402
from msfsu_interfaces.msg import DrivingAction, Route, VehicleControl  # noqa: E402

FRAMES = 15


class ScriptedController(Node):
    """Answers every camera frame with a fixed control stamped like the frame, after a delay."""

    def __init__(self, context: Context, steer: float = 0.0, frames: int = FRAMES, delay_s: float = 0.3) -> None:
        super().__init__("scripted_controller", context=context)
        self.steer, self.frames, self.delay_s = steer, frames, delay_s
        qos = QoSProfile(depth=5, reliability=ReliabilityPolicy.RELIABLE)
        self.publisher = self.create_publisher(VehicleControl, topics.VEHICLE_CONTROL, qos)
        self.create_subscription(Image, topics.RGB, self.on_image, qos)
        self.create_subscription(Clock, topics.CLOCK, lambda msg: self.clock.append(msg.clock), qos)
        self.create_subscription(DrivingAction, topics.EXPERT_ACTION, lambda msg: self.actions.append(msg), qos)
        self.images: list[Image] = []
        self.clock = []
        self.actions: list[DrivingAction] = []

    def on_image(self, image: Image) -> None:
        self.images.append(image)
        time.sleep(self.delay_s)  # a slow controller: lockstep must wait for it, not run ahead
        if len(self.images) <= self.frames:
            self.publisher.publish(VehicleControl(header=image.header, throttle=0.6, steer=self.steer, brake=0.0))


def test_bridge_steps_once_per_control_in_lockstep(sim):
    from msfsu_sim.bridge_node import SimBridge

    context = Context()
    rclpy.init(context=context)
    executor = SingleThreadedExecutor(context=context)
    controller = ScriptedController(context)
    routes: list[Route] = []
    controller.create_subscription(Route, topics.ROUTE, routes.append,
                                   QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                                              durability=rclpy.qos.DurabilityPolicy.TRANSIENT_LOCAL))
    bridge = SimBridge(sim, [Parameter("control_timeout", value=30.0), Parameter("seed", value=3)], context)
    executor.add_node(bridge)
    executor.add_node(controller)
    try:
        deadline = time.monotonic() + 120
        while len(controller.images) < FRAMES + 1 and time.monotonic() < deadline:
            executor.spin_once(timeout_sec=0.05)
        quiet_until = time.monotonic() + 1.0  # no control for the last frame: the bridge must not step
        while time.monotonic() < quiet_until:
            executor.spin_once(timeout_sec=0.05)
    finally:
        executor.shutdown()
        bridge.destroy_node()
        controller.destroy_node()
        rclpy.shutdown(context=context)
    stamps = [i.header.stamp.sec + i.header.stamp.nanosec * 1e-9 for i in controller.images]
    assert len(stamps) == FRAMES + 1
    assert stamps == pytest.approx([0.1 * k for k in range(FRAMES + 1)])
    assert bridge.lockstep_steps == FRAMES and bridge.timeout_steps == 0
    assert bridge.obs.odometry.speed > 0.5  # the scripted throttle was applied
    assert len(controller.clock) == FRAMES + 1 and len(controller.actions) == FRAMES + 1
    assert len(routes) == 1 and len(routes[0].poses) == len(routes[0].options) > 10


def test_bridge_logs_status_and_exits_after_the_episodes_asked_for(sim, capfd):
    from msfsu_common.node_runner import NodeFinished
    from msfsu_sim.bridge_node import SimBridge

    context = Context()
    rclpy.init(context=context)
    executor = SingleThreadedExecutor(context=context)
    controller = ScriptedController(context, steer=1.0, frames=10**6, delay_s=0.0)  # hard right: off the road
    parameters = [Parameter("control_timeout", value=30.0), Parameter("episodes", value=1),
                  Parameter("status_period", value=1.0), Parameter("traffic", value="empty")]
    bridge = SimBridge(sim, parameters, context)
    executor.add_node(bridge)
    executor.add_node(controller)
    finished = False
    try:
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline:
            executor.spin_once(timeout_sec=0.05)
    except NodeFinished:
        finished = True
    finally:
        executor.shutdown()
        bridge.destroy_node()
        controller.destroy_node()
        rclpy.shutdown(context=context)
    log = capfd.readouterr().err
    assert finished, log[-2000:]
    assert bridge.status.outcomes and bridge.episode == 1
    assert "episode 0 |    1.0 s | route " in log and "steps 10 lockstep / 0 timeout" in log
    assert "ended: " in log and "1 episode: 1 " in log


def test_free_running_bridge_steps_on_the_wall_clock_with_the_last_control(sim):
    """real_time_factor > 0: the bridge does not wait; a controller that falls silent leaves its last control on."""
    from msfsu_sim.bridge_node import SimBridge

    context = Context()
    rclpy.init(context=context)
    executor = SingleThreadedExecutor(context=context)
    controller = ScriptedController(context, frames=5, delay_s=0.0)  # answers the first 5 frames, then nothing
    parameters = [Parameter("real_time_factor", value=1.0), Parameter("seed", value=3),
                  Parameter("traffic", value="empty")]
    bridge = SimBridge(sim, parameters, context)
    executor.add_node(bridge)
    executor.add_node(controller)
    try:
        started = time.monotonic()
        while time.monotonic() - started < 3.0:
            executor.spin_once(timeout_sec=0.01)
        record = bridge.pacer.record()
    finally:
        executor.shutdown()
        bridge.destroy_node()
        controller.destroy_node()
        rclpy.shutdown(context=context)
    steps = bridge.lockstep_steps + bridge.timeout_steps
    assert 15 <= steps <= 31  # 10 steps a wall second (less when the simulator's own step is slower)
    assert bridge.lockstep_steps <= 5 and bridge.timeout_steps >= 10  # no control for its frame after the fifth
    assert record["steps"] == steps and 0.5 <= record["achieved_real_time_factor"] <= 1.05
    ages = {int(age): count for age, count in record["control_age_steps"].items()}
    assert max(ages) >= 10  # the fifth frame's control still applies, ever older
    assert bridge.obs.odometry.speed > 0.5  # it keeps the car going: the last control was throttle 0.6
