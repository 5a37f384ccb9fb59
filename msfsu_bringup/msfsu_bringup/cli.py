"""Command-line options that become ROS parameter overrides, so a tool takes both
`bag_player BAG --rate 2` and `--ros-args -p bag:=BAG -p rate:=2.0` (bringup profiles)."""

from __future__ import annotations

import argparse
from collections.abc import Sequence

from rclpy.parameter import Parameter
from rclpy.utilities import remove_ros_args


def parameter_overrides(parser: argparse.ArgumentParser, argv: Sequence[str]) -> list[Parameter]:
    """Parse the non-ROS part of argv; every option given (not None) becomes a parameter override."""
    options = parser.parse_args(remove_ros_args(list(argv))[1:])
    return [Parameter(name, value=value) for name, value in vars(options).items() if value is not None]
