"""The camera transport: the shipped Fast DDS profile, how the environment applies it, and a 1.4 MB frame over it."""

import json
import os
import subprocess
import sys
from pathlib import Path


from msfsu_common.ros_env import configure_ros_environment
from msfsu_common.transport import (FASTDDS_PROFILE, PROFILE_VARIABLE, USER_PROFILE_VARIABLES, largest_sensor_pair_bytes,
                                    profile_segment_bytes, required_segment_bytes, required_shm_bytes)

PROBE = Path(__file__).parents[2] / "tests" / "shm_probe.py"
FRAMES = 20


def test_the_profile_segment_holds_the_sensor_queue_of_the_largest_pair():
    assert largest_sensor_pair_bytes() == 2 * 1920 * 1080 * 4
    assert profile_segment_bytes() == required_segment_bytes() >= 5 * largest_sensor_pair_bytes()


def test_the_environment_applies_the_profile_unless_the_user_named_one():
    assert configure_ros_environment({})[PROFILE_VARIABLE] == str(FASTDDS_PROFILE)
    assert configure_ros_environment({})["ROS_AUTOMATIC_DISCOVERY_RANGE"] == "LOCALHOST"
    assert configure_ros_environment({PROFILE_VARIABLE: ""})[PROFILE_VARIABLE] == str(FASTDDS_PROFILE)
    assert configure_ros_environment({PROFILE_VARIABLE: "/mine.xml"})[PROFILE_VARIABLE] == "/mine.xml"
    mine = configure_ros_environment({"FASTDDS_DEFAULT_PROFILES_FILE": "/mine3.xml"})
    assert PROFILE_VARIABLE not in mine and mine["FASTDDS_DEFAULT_PROFILES_FILE"] == "/mine3.xml"


def test_a_shared_memory_too_small_for_the_segments_keeps_the_defaults_and_says_so(monkeypatch, capsys):
    from msfsu_common import ros_env

    monkeypatch.setattr(ros_env, "shm_capacity_bytes", lambda: 64 << 20)  # a container's default /dev/shm
    environ = configure_ros_environment({})
    assert PROFILE_VARIABLE not in environ and environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] == "LOCALHOST"
    message = capsys.readouterr().err
    assert message.count("\n") == 1 and "/dev/shm holds 64 MiB" in message and "--shm-size" in message
    monkeypatch.setattr(ros_env, "shm_capacity_bytes", lambda: required_shm_bytes())
    assert configure_ros_environment({})[PROFILE_VARIABLE] == str(FASTDDS_PROFILE)



def test_the_stacks_own_profile_preset_is_checked_like_no_profile(monkeypatch, capsys):
    """The Docker entrypoint exports the stack's profile for the ros2 CLI tools: not a profile of the user's, so a
    /dev/shm too small for it still falls back to the defaults (and `python -m msfsu_common.ros_env` prints none)."""
    from msfsu_common import ros_env

    monkeypatch.setattr(ros_env, "shm_capacity_bytes", lambda: 64 << 20)
    for name in USER_PROFILE_VARIABLES:
        assert PROFILE_VARIABLE not in configure_ros_environment({name: str(FASTDDS_PROFILE)})
    monkeypatch.setenv(PROFILE_VARIABLE, str(FASTDDS_PROFILE))
    capsys.readouterr()
    assert ros_env.main() == 0
    printed = capsys.readouterr()
    assert printed.out == "\n" and "/dev/shm holds 64 MiB" in printed.err
    monkeypatch.setenv(PROFILE_VARIABLE, "/mine.xml")
    ros_env.main()
    assert capsys.readouterr().out == "/mine.xml\n"
    monkeypatch.setattr(ros_env, "shm_capacity_bytes", lambda: required_shm_bytes())
    monkeypatch.delenv(PROFILE_VARIABLE)
    ros_env.main()
    assert capsys.readouterr().out == f"{FASTDDS_PROFILE}\n"

def exchange(environ: dict[str, str]) -> tuple[dict, dict]:
    """`FRAMES` 800x600 rgb8 images from one process to another; (publisher report, subscriber report)."""
    subscriber = subprocess.Popen([sys.executable, str(PROBE), "sub", str(FRAMES)], env=environ,
                                  stdout=subprocess.PIPE, text=True)
    publisher = subprocess.run([sys.executable, str(PROBE), "pub", str(FRAMES)], env=environ,
                               capture_output=True, text=True, timeout=60)
    received, _ = subscriber.communicate(timeout=60)
    assert publisher.returncode == 0 and subscriber.returncode == 0, publisher.stderr[-2000:]
    return json.loads(publisher.stdout.splitlines()[-1]), json.loads(received.splitlines()[-1])


def big_segment_written(report: dict) -> bool:
    """A mapped segment of the profile's size holds a probed piece of the frame (64 random bytes: found, they were
    written there), so the frame crossed through it. Not all 8 pieces: freed buffers get written over (one run in
    ~20 found 4)."""
    return any(s["size"] >= required_segment_bytes() and s["frame_pieces_found"] >= 1 for s in report["segments"])


def test_a_camera_frame_crosses_between_processes_through_the_profile_segment(tmp_path):
    # The processes get the project's environment (conftest applied it): the frames must have been written into a
    # segment of the profile's size, which the 0.5 MB default segment cannot be.
    sent, received = exchange(dict(os.environ))
    assert received["received"] == FRAMES
    assert big_segment_written(sent), sent

    # Control: a user's own profile (here: Fast DDS's defaults) is respected, and then no such segment exists.
    user_profile = tmp_path / "defaults.xml"
    user_profile.write_text('<?xml version="1.0"?>\n<dds xmlns="http://www.eprosima.com/XMLSchemas/fastRTPS_Profiles">'
                            '<profiles/></dds>\n')
    sent, received = exchange(dict(os.environ, **{PROFILE_VARIABLE: str(user_profile)}))
    assert received["received"] == FRAMES
    assert not big_segment_written(sent), sent
