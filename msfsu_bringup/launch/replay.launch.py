"""`ros2 launch msfsu_bringup replay.launch.py NAME:=VALUE ...`: the replay profile.

The graph of profiles/replay.yaml, which `python -m msfsu_bringup replay` also starts, with the profile's arguments
as launch arguments (msfsu_bringup.launch_description).
"""

from msfsu_bringup.launch_description import profile_launch_description


def generate_launch_description():
    return profile_launch_description("replay")
