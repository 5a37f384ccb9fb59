"""How camera frames cross between the stack's processes: Fast DDS over shared memory, sized for them.

Jazzy's Fast DDS (2.14) gives every participant a 0.5 MB shared-memory segment. An 800x600 rgb8 frame
(1.4 MB) or 32FC1 depth frame (1.9 MB) is split into 64 kB fragments that do not all fit in it: with
reliable QoS a fragment that found no room waits for a retransmission (hundreds of ms), with best effort
the frame is lost. `fastdds_profile.xml` gives every participant one shared-memory segment that holds
`SENSOR_QUEUE_DEPTH` pairs of the largest camera the stack declares, plus UDPv4 for other hosts
(`MSFSU_DISCOVERY_RANGE=SUBNET`; with LOCALHOST discovery rmw_fastrtps adds its own UDP and small
shared-memory transports after the profile's, which then carry only discovery and small messages).
Fast DDS 2.x reads the profile from `FASTRTPS_DEFAULT_PROFILES_FILE` only (FASTDDS_... is the 3.x name);
`msfsu_common.ros_env` sets it for every process of the stack unless the user named a profile, or unless
/dev/shm is too small for the segments (a container's default 64 MB), which it says in one line: there Fast DDS
cannot create the segment, logs three errors per process and runs on its other transports anyway.
"""

from __future__ import annotations

import os
import xml.etree.ElementTree as ElementTree
from pathlib import Path

FASTDDS_PROFILE = Path(__file__).with_name("fastdds_profile.xml")
PROFILE_VARIABLE = "FASTRTPS_DEFAULT_PROFILES_FILE"  # read by Fast DDS 2.x (Jazzy)
USER_PROFILE_VARIABLES = (PROFILE_VARIABLE, "FASTDDS_DEFAULT_PROFILES_FILE")  # a user's own profile: left alone

MAX_CAMERA_WIDTH, MAX_CAMERA_HEIGHT = 1920, 1080  # the largest camera the stack declares (sim_bridge, soak)
MAX_BYTES_PER_PIXEL = 4  # bgra8 (carla-ros-bridge RGB) and 32FC1 (metric depth)
SENSOR_QUEUE_DEPTH = 5  # history depth of the reliable sensor publishers and subscriptions
_MIB = 1 << 20
SHM_DIRECTORY = Path("/dev/shm")
# ROS processes a graph of the stack runs at once on one machine (simulator, route, perception, control, recorder,
# player, a tool or two): /dev/shm must hold a segment for each, plus Fast DDS's own overhead (5 %).
SHM_PROCESSES = 8


def largest_sensor_pair_bytes() -> int:
    """Bytes of one RGB + depth pair at the largest declared camera size."""
    return 2 * MAX_CAMERA_WIDTH * MAX_CAMERA_HEIGHT * MAX_BYTES_PER_PIXEL


def required_segment_bytes() -> int:
    """Shared-memory segment that holds SENSOR_QUEUE_DEPTH of the largest pairs, rounded up to a MiB."""
    return -(-SENSOR_QUEUE_DEPTH * largest_sensor_pair_bytes() // _MIB) * _MIB


def required_shm_bytes() -> int:
    """/dev/shm the stack's graph needs with the profile: SHM_PROCESSES segments and their overhead."""
    return int(SHM_PROCESSES * required_segment_bytes() * 1.05)


def shm_capacity_bytes(directory: Path = SHM_DIRECTORY) -> int | None:
    """Size of the shared-memory file system (None where there is none, e.g. not Linux)."""
    try:
        stats = os.statvfs(directory)
    except OSError:
        return None
    return stats.f_blocks * stats.f_frsize


def profile_segment_bytes(path: Path = FASTDDS_PROFILE) -> int:
    """The `segment_size` of the SHM transport a Fast DDS XML profile declares."""
    namespace = {"dds": "http://www.eprosima.com/XMLSchemas/fastRTPS_Profiles"}
    for descriptor in ElementTree.parse(path).getroot().iterfind(".//dds:transport_descriptor", namespace):
        if descriptor.findtext("dds:type", namespaces=namespace) == "SHM":
            return int(descriptor.findtext("dds:segment_size", namespaces=namespace))
    raise ValueError(f"{path} declares no SHM transport")
