"""Process environment every rclpy process of the stack starts with.

Discovery is kept on this host (`ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST`): the ROS 2 default
multicasts to the whole subnet. A robot that needs the network sets MSFSU_DISCOVERY_RANGE explicitly.
Camera frames cross over shared memory sized for them (the stack's Fast DDS profile, msfsu_common.transport),
unless the user named a profile of their own or /dev/shm is too small for it (then one line says so on stderr).
A profile variable that names the stack's own profile (the Docker entrypoint exports it for the ros2 CLI tools)
is not the user's: the /dev/shm check applies to it too.

    python -m msfsu_common.ros_env   # prints the profile the stack's processes use here ("" = Fast DDS defaults)
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


def user_profile(value: str) -> bool:
    """A profile variable's value names a profile of the user's: set, and not the stack's own."""
    return bool(value) and Path(value).resolve() != FASTDDS_PROFILE.resolve()


def configure_ros_environment(environ: MutableMapping[str, str] = os.environ) -> MutableMapping[str, str]:
    """Set discovery range, the Fast DDS profile and a writable ROS log directory in `environ` (before rclpy.init)."""
    environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = environ.get(DISCOVERY_OVERRIDE, "LOCALHOST")
    if not any(user_profile(environ.get(name, "")) for name in USER_PROFILE_VARIABLES):
        capacity = shm_capacity_bytes()
        if capacity is None or capacity >= required_shm_bytes():
            environ[PROFILE_VARIABLE] = str(FASTDDS_PROFILE)
        else:
            environ.pop(PROFILE_VARIABLE, None)
            print(f"msfsu: /dev/shm holds {capacity >> 20} MiB, the stack's shared-memory transport needs "
                  f"{required_shm_bytes() >> 20} MiB: camera frames use Fast DDS's default transports (slow for large "
                  "images); give the container more (docker run --shm-size=1g)", file=sys.stderr)
    if "ROS_LOG_DIR" not in environ:
        home = environ.get("HOME")
        base = Path(home) / ".ros" if home else Path(tempfile.gettempdir()) / "msfsu_ros"
        environ["ROS_LOG_DIR"] = str(base / "log")
    return environ


def main() -> int:
    """Print the Fast DDS profile this environment gives the stack's processes (empty: Fast DDS's defaults)."""
    print(configure_ros_environment(dict(os.environ)).get(PROFILE_VARIABLE, ""))
    return 0


if __name__ == "__main__":
    sys.exit(main())
