"""`ros2 launch msfsu_bringup agent.launch.py NAME:=VALUE ...`: the agent profile.

The graph of profiles/agent.yaml, which `python -m msfsu_bringup agent` also starts, with the profile's arguments as
launch arguments (msfsu_bringup.launch_description).
"""

from msfsu_bringup.launch_description import profile_launch_description


def generate_launch_description():
    return profile_launch_description("agent")
