"""`ros2 launch msfsu_bringup sim_expert.launch.py NAME:=VALUE ...`: the sim_expert profile.

The graph of profiles/sim_expert.yaml, which `python -m msfsu_bringup sim_expert` also starts, with the profile's
arguments as launch arguments (msfsu_bringup.launch_description).
"""

from msfsu_bringup.launch_description import profile_launch_description


def generate_launch_description():
    return profile_launch_description("sim_expert")
