"""`ros2 launch msfsu_bringup sim.launch.py NAME:=VALUE ...`: the sim profile.

The graph of profiles/sim.yaml, which `python -m msfsu_bringup sim` also starts, with the profile's arguments as
launch arguments (msfsu_bringup.launch_description).
"""

from msfsu_bringup.launch_description import profile_launch_description


def generate_launch_description():
    return profile_launch_description("sim")
