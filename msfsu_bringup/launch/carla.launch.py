"""`ros2 launch msfsu_bringup carla.launch.py NAME:=VALUE ...`: the carla profile.

The graph of profiles/carla.yaml, which `python -m msfsu_bringup carla` also starts, with the profile's arguments as
launch arguments (msfsu_bringup.launch_description).
"""

from msfsu_bringup.launch_description import profile_launch_description


def generate_launch_description():
    return profile_launch_description("carla")
