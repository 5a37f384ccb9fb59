"""Process environment every rclpy process of the stack starts with.

Discovery is kept on this host (`ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST`): the ROS 2 default
multicasts to the whole subnet. A robot that needs the network sets MSFSU_DISCOVERY_RANGE explicitly.
Camera frames cross over shared memory sized for them (the stack's Fast DDS profile, msfsu_common.transport),
unless the user named a profile of their own or /dev/shm is too small for it (then one line says so on stderr).
"""

from __future__ import annotations

import os
import sys
import tempfile
from collections.abc import MutableMapping
from pathlib import Path

from msfsu_common.transport import (FASTDDS_PROFILE, PROFILE_VARIABLE, USER_PROFILE_VARIABLES, required_shm_bytes,
                                    shm_capacity_bytes)

DISCOVERY_OVERRIDE = "MSFSU_DISCOVERY_RANGE"


def configure_ros_environment(environ: MutableMapping[str, str] = os.environ) -> MutableMapping[str, str]:
    """Set discovery range, the Fast DDS profile and a writable ROS log directory in `environ` (before rclpy.init)."""
    environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = environ.get(DISCOVERY_OVERRIDE, "LOCALHOST")
    if not any(environ.get(name) for name in USER_PROFILE_VARIABLES):
        capacity = shm_capacity_bytes()
        if capacity is None or capacity >= required_shm_bytes():
            environ[PROFILE_VARIABLE] = str(FASTDDS_PROFILE)
        else:
            print(f"msfsu: /dev/shm holds {capacity >> 20} MiB, the stack's shared-memory transport needs "
                  f"{required_shm_bytes() >> 20} MiB: camera frames use Fast DDS's default transports (slow for large "
                  "images); give the container more (docker run --shm-size=1g)", file=sys.stderr)
    if "ROS_LOG_DIR" not in environ:
        home = environ.get("HOME")
        base = Path(home) / ".ros" if home else Path(tempfile.gettempdir()) / "msfsu_ros"
        environ["ROS_LOG_DIR"] = str(base / "log")
    return environ
