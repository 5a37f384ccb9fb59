"""Process environment every rclpy process of the stack starts with.

Discovery is kept on this host (`ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST`): the ROS 2 default
multicasts to the whole subnet. A robot that needs the network sets MSFSU_DISCOVERY_RANGE explicitly.
"""

from __future__ import annotations

import os
import tempfile
from collections.abc import MutableMapping
from pathlib import Path

DISCOVERY_OVERRIDE = "MSFSU_DISCOVERY_RANGE"


def configure_ros_environment(environ: MutableMapping[str, str] = os.environ) -> MutableMapping[str, str]:
    """Set discovery range and a writable ROS log directory in `environ` (before rclpy.init)."""
    environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = environ.get(DISCOVERY_OVERRIDE, "LOCALHOST")
    if "ROS_LOG_DIR" not in environ:
        home = environ.get("HOME")
        base = Path(home) / ".ros" if home else Path(tempfile.gettempdir()) / "msfsu_ros"
        environ["ROS_LOG_DIR"] = str(base / "log")
    return environ
