"""Simulator state -> ROS messages, for both rosbags (bags) and rclpy (live bridge).

The two libraries have different message classes with the same fields; `MessageBuilder` takes the
classes by type name, so every field is filled in one place. All fields are passed (rosbags
dataclasses have no defaults).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numpy as np

from msfsu_common import topics
from msfsu_common.image_codec import encode_image
from msfsu_sim.environment import Observation
from msfsu_sim.expert import ExpertAction
from msfsu_sim.route import Route

MAP_FRAME = "map"
EGO_FRAME = topics.ROLE
CAMERA_FRAMES = {"rgb": f"{topics.ROLE}/rgb_front", "depth": f"{topics.ROLE}/depth_front",
                 "semantic": f"{topics.ROLE}/semantic_front"}
TYPES = {
    topics.RGB: "sensor_msgs/msg/Image", topics.DEPTH: "sensor_msgs/msg/Image",
    topics.SEMANTIC_IDS: "sensor_msgs/msg/Image", topics.ODOMETRY: "nav_msgs/msg/Odometry",
    topics.EXPERT_ACTION: "msfsu_interfaces/msg/DrivingAction", topics.DRIVING_ACTION: "msfsu_interfaces/msg/DrivingAction",
    topics.VEHICLE_CONTROL: "msfsu_interfaces/msg/VehicleControl",
    topics.NAVIGATION_COMMAND: "msfsu_interfaces/msg/NavigationCommand",
    topics.ROUTE: "msfsu_interfaces/msg/Route", topics.NOISE_INJECTION: "std_msgs/msg/Bool",
    topics.NETWORK_DRIVING: "std_msgs/msg/Bool", topics.EXPERT_LIMITED_BY: "std_msgs/msg/String",
    topics.CLOCK: "rosgraph_msgs/msg/Clock", topics.WAYPOINTS: "nav_msgs/msg/Path",
}


def yaw_quaternion(yaw: float) -> tuple[float, float, float, float]:
    """(x, y, z, w) of a rotation by `yaw` about z."""
    return 0.0, 0.0, math.sin(yaw / 2), math.cos(yaw / 2)


class MessageBuilder:
    """`classes(name)` returns the message class of a type name ("sensor_msgs/msg/Image");
    `pack(array)` converts a uint8/float64 numpy array to what that library stores in sequences."""

    def __init__(self, classes: Callable[[str], Any], pack: Callable[[np.ndarray], Any]) -> None:
        self._cls, self._pack = classes, pack

    def stamp(self, time_s: float) -> Any:
        nanoseconds = round(time_s * 1e9)
        return self._cls("builtin_interfaces/msg/Time")(sec=nanoseconds // 10**9, nanosec=nanoseconds % 10**9)

    def header(self, time_s: float, frame_id: str) -> Any:
        return self._cls("std_msgs/msg/Header")(stamp=self.stamp(time_s), frame_id=frame_id)

    def image(self, time_s: float, frame_id: str, pixels: np.ndarray, encoding: str) -> Any:
        fields = encode_image(pixels, encoding)
        fields["data"] = self._pack(np.frombuffer(fields["data"], np.uint8))
        return self._cls("sensor_msgs/msg/Image")(header=self.header(time_s, frame_id), **fields)

    def pose(self, x: float, y: float, yaw: float) -> Any:
        qx, qy, qz, qw = yaw_quaternion(yaw)
        return self._cls("geometry_msgs/msg/Pose")(
            position=self._cls("geometry_msgs/msg/Point")(x=x, y=y, z=0.0),
            orientation=self._cls("geometry_msgs/msg/Quaternion")(x=qx, y=qy, z=qz, w=qw))

    def odometry(self, obs: Observation) -> Any:
        odo = obs.odometry
        vector = self._cls("geometry_msgs/msg/Vector3")
        twist = self._cls("geometry_msgs/msg/Twist")(linear=vector(x=odo.speed, y=0.0, z=0.0),
                                                      angular=vector(x=0.0, y=0.0, z=odo.yaw_rate))
        covariance = self._pack(np.zeros(36, np.float64))
        return self._cls("nav_msgs/msg/Odometry")(
            header=self.header(obs.time_s, MAP_FRAME), child_frame_id=EGO_FRAME,
            pose=self._cls("geometry_msgs/msg/PoseWithCovariance")(pose=self.pose(odo.x, odo.y, odo.yaw),
                                                                   covariance=covariance),
            twist=self._cls("geometry_msgs/msg/TwistWithCovariance")(twist=twist, covariance=covariance))

    def driving_action(self, time_s: float, action: ExpertAction) -> Any:
        return self._cls(TYPES[topics.EXPERT_ACTION])(header=self.header(time_s, EGO_FRAME), steer=action.steer,
                                                       target_speed=action.target_speed,
                                                       command=int(action.command))

    def vehicle_control(self, time_s: float, throttle: float, steer: float, brake: float) -> Any:
        return self._cls(TYPES[topics.VEHICLE_CONTROL])(header=self.header(time_s, EGO_FRAME), throttle=throttle,
                                                         steer=steer, brake=brake, hand_brake=False, reverse=False)

    def navigation_command(self, time_s: float, command: int) -> Any:
        return self._cls(TYPES[topics.NAVIGATION_COMMAND])(header=self.header(time_s, EGO_FRAME),
                                                            command=int(command))

    def route(self, time_s: float, route: Route) -> Any:
        poses = [self.pose(float(x), float(y), float(yaw)) for x, y, yaw in route.poses]
        return self._cls(TYPES[topics.ROUTE])(header=self.header(time_s, MAP_FRAME), poses=poses,
                                               options=self._pack(route.options.astype(np.uint8)))

    def path(self, time_s: float, route: Route) -> Any:
        """The route as carla-ros-bridge's waypoint publisher sends one: a nav_msgs/Path of its poses, no options."""
        header = self.header(time_s, MAP_FRAME)
        stamped = self._cls("geometry_msgs/msg/PoseStamped")
        poses = [stamped(header=header, pose=self.pose(float(x), float(y), float(yaw))) for x, y, yaw in route.poses]
        return self._cls(TYPES[topics.WAYPOINTS])(header=header, poses=poses)

    def flag(self, value: bool) -> Any:
        return self._cls("std_msgs/msg/Bool")(data=bool(value))

    def text(self, value: str) -> Any:
        return self._cls("std_msgs/msg/String")(data=str(value))

    def clock(self, time_s: float) -> Any:
        return self._cls("rosgraph_msgs/msg/Clock")(clock=self.stamp(time_s))

    def sensors(self, obs: Observation) -> dict[str, Any]:
        """Camera images (class ids when rendered) and odometry of one frame, by default topic, in the order to
        publish them: the clock, then the small messages, then the images. A node that acts on an image (perception,
        and control on perception's action) then has the frame's odometry and command already: in lockstep the graph
        answers a frame the same way however busy the machine is."""
        t = obs.time_s
        messages = {
            topics.CLOCK: self.clock(t),
            topics.ODOMETRY: self.odometry(obs),
            topics.NAVIGATION_COMMAND: self.navigation_command(t, obs.command),
            topics.RGB: self.image(t, CAMERA_FRAMES["rgb"], obs.rgb, "rgb8"),
            topics.DEPTH: self.image(t, CAMERA_FRAMES["depth"], obs.depth, "32FC1"),
        }
        if obs.semantic_ids is not None:
            messages[topics.SEMANTIC_IDS] = self.image(t, CAMERA_FRAMES["semantic"], obs.semantic_ids, "mono8")
        return messages


def rosbags_builder(typestore: Any) -> MessageBuilder:
    return MessageBuilder(lambda name: typestore.types[name], lambda array: array)

