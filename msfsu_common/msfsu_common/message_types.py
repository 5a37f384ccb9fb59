"""Message classes from their type names, as bags and the ROS graph spell them; header stamps as integers; a pose's yaw."""

from __future__ import annotations

import importlib
import math
from typing import Any


def message_class(type_name: str) -> type:
    """'sensor_msgs/msg/Image' -> sensor_msgs.msg.Image (the package must be installed)."""
    package, kind, name = type_name.split("/")
    try:
        return getattr(importlib.import_module(f"{package}.{kind}"), name)
    except (ImportError, AttributeError) as error:
        raise LookupError(f"message type {type_name} is not installed: {error}") from error


def stamp_ns(header: Any) -> int:
    """A std_msgs/Header stamp (rclpy or rosbags message) as integer nanoseconds.

    Plain arithmetic on whatever the fields hold: a negative `sec` (int32) or a `nanosec` past one second
    come from broken publishers and must give a number, not an exception (rclpy's Time refuses them).
    """
    return int(header.stamp.sec) * 1_000_000_000 + int(header.stamp.nanosec)


def yaw_of(orientation: Any) -> float:
    """A geometry_msgs Quaternion -> its rotation about z, radians counter-clockwise (the heading of a planar pose)."""
    return math.atan2(2 * (orientation.w * orientation.z + orientation.x * orientation.y),
                      1 - 2 * (orientation.y ** 2 + orientation.z ** 2))
