"""msfsu-bag-video renders a short synthetic bag (CARLA-bridge style bgra8 camera, the graph's outputs)
into an H.264 MP4 that decodes back frame for frame, with the segmentation where the network saw."""

import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from msfsu_common import topics
from msfsu_common.bag_io import mcap_writer, msfsu_typestore
from msfsu_common.image_codec import encode_image
from msfsu_evaluation.video import read_video

N_FRAMES = 25
WIDTH, HEIGHT = 160, 120
GREY = 100
AGENT = 3  # class id drawn blue (0, 0, 142)
BROKEN_FRAME = 7  # its RGB message is truncated: dropped and counted, not a traceback
COMMAND = [sys.executable, "-m", "msfsu_evaluation.bag_video"]


def write_bag(path: Path) -> None:
    store = msfsu_typestore()
    types = store.types

    def header(stamp_ns: int, frame_id: str = "ego_vehicle"):
        stamp = types["builtin_interfaces/msg/Time"](sec=stamp_ns // 10**9, nanosec=stamp_ns % 10**9)
        return types["std_msgs/msg/Header"](stamp=stamp, frame_id=frame_id)

    def image(stamp_ns: int, pixels: np.ndarray, encoding: str):
        fields = encode_image(pixels, encoding)
        fields["data"] = np.frombuffer(fields["data"], np.uint8)
        return types["sensor_msgs/msg/Image"](header=header(stamp_ns), **fields)

    def pose(x: float, y: float, yaw: float):
        return types["geometry_msgs/msg/Pose"](
            position=types["geometry_msgs/msg/Point"](x=x, y=y, z=0.0),
            orientation=types["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=math.sin(yaw / 2), w=math.cos(yaw / 2)))

    vector = types["geometry_msgs/msg/Vector3"]
    covariance = np.zeros(36, np.float64)
    with mcap_writer(path) as writer:
        connection = {topic: writer.add_connection(topic, msgtype, typestore=store) for topic, msgtype in (
            (topics.RGB, "sensor_msgs/msg/Image"), (topics.SEGMENTATION, "sensor_msgs/msg/Image"),
            (topics.DRIVING_ACTION, "msfsu_interfaces/msg/DrivingAction"),
            (topics.VEHICLE_CONTROL, "msfsu_interfaces/msg/VehicleControl"),
            (topics.ODOMETRY, "nav_msgs/msg/Odometry"), (topics.ROUTE, "msfsu_interfaces/msg/Route"),
            (topics.NAVIGATION_COMMAND, "msfsu_interfaces/msg/NavigationCommand"))}

        def write(topic: str, log_ns: int, msg) -> None:
            writer.write(connection[topic], log_ns, store.serialize_cdr(msg, msg.__msgtype__))

        start = 1_700_000_000 * 10**9  # wall-clock stamps, as on a car
        route = types["msfsu_interfaces/msg/Route"](
            header=header(start, "map"), poses=[pose(2.0 * i, 0.0, 0.0) for i in range(30)],
            options=np.full(30, 4, np.uint8))
        write(topics.ROUTE, start, route)
        for index in range(N_FRAMES):
            stamp = start + index * 100_000_000
            bgra = np.full((HEIGHT, WIDTH, 4), GREY, np.uint8)
            rgb = image(stamp, bgra, "bgra8")
            if index == BROKEN_FRAME:
                rgb.data = rgb.data[:-10]
            write(topics.RGB, stamp + 1_000_000, rgb)
            write(topics.NAVIGATION_COMMAND, stamp, types["msfsu_interfaces/msg/NavigationCommand"](
                header=header(stamp), command=1 if index > 12 else 4))
            twist = types["geometry_msgs/msg/Twist"](linear=vector(x=5.0, y=0.0, z=0.0),
                                                     angular=vector(x=0.0, y=0.0, z=0.0))
            write(topics.ODOMETRY, stamp, types["nav_msgs/msg/Odometry"](
                header=header(stamp, "map"), child_frame_id="ego_vehicle",
                pose=types["geometry_msgs/msg/PoseWithCovariance"](pose=pose(0.5 * index, 0.0, 0.0),
                                                                   covariance=covariance),
                twist=types["geometry_msgs/msg/TwistWithCovariance"](twist=twist, covariance=covariance)))
            # the network's outputs carry the camera stamp and are logged after it
            write(topics.SEGMENTATION, stamp + 20_000_000, image(stamp, np.full((32, 32), AGENT, np.uint8), "mono8"))
            write(topics.DRIVING_ACTION, stamp + 20_000_000, types["msfsu_interfaces/msg/DrivingAction"](
                header=header(stamp), steer=0.3, target_speed=6.0, command=4))
            write(topics.VEHICLE_CONTROL, stamp + 25_000_000, types["msfsu_interfaces/msg/VehicleControl"](
                header=header(stamp), throttle=0.4, steer=0.3, brake=0.0, hand_brake=False, reverse=False))


@pytest.fixture(scope="module")
def bag(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("bags") / "drive"
    write_bag(path)
    return path


def test_bag_renders_to_a_playable_h264_mp4_frame_for_frame(bag, tmp_path):
    output = tmp_path / "drive.mp4"
    run = subprocess.run(COMMAND + [str(bag), "-o", str(output)], capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stderr[-2000:]
    assert f"{N_FRAMES - 1} frames at 10 fps" in run.stdout and "dropped rgb:" in run.stdout
    assert "render " in run.stdout and "ffmpeg CPU" in run.stdout and not list(tmp_path.glob("*.partial.mp4"))
    meta, frames = read_video(output)
    assert meta["codec"] == "h264" and meta["size"] == (WIDTH, HEIGHT) and meta["fps"] == 10
    assert len(frames) == N_FRAMES - 1  # one per decodable camera frame
    last = frames[-1].astype(int)
    # bottom half (what the network saw, crop_top_fraction 0.5): the predicted class tints the grey blue
    red, green, blue = last[100, 80]
    assert blue > red + 20 and abs(red - green) < 15
    # top half, outside the text panel and the inset: the camera image untouched
    assert np.abs(last[55, 80] - GREY).max() < 12


def test_bag_without_the_camera_topic_is_a_usage_error(bag, tmp_path):
    run = subprocess.run(COMMAND + [str(bag), "-o", str(tmp_path / "x.mp4"), "--remap",
                                    f"{topics.ODOMETRY}:={topics.RGB}"], capture_output=True, text=True, timeout=60)
    assert run.returncode == 2 and "carries nav_msgs/msg/Odometry" in run.stderr
    missing = subprocess.run(COMMAND + [str(tmp_path / "none"), "-o", str(tmp_path / "x.mp4")],
                             capture_output=True, text=True, timeout=60)
    assert missing.returncode == 2 and "no metadata.yaml" in missing.stderr
    assert not (tmp_path / "x.mp4").exists()


def test_renderer_inset_shows_route_path_and_car_and_skips_non_finite_poses():
    from msfsu_evaluation.video import CAR_COLOUR, PATH_COLOUR, ROUTE_COLOUR, DriveRenderer, DriveState

    renderer = DriveRenderer()
    renderer.set_route(np.array([[0.0, 0.0], [100.0, 0.0], [100.0, 50.0]]))
    black = np.zeros((300, 400, 3), np.uint8)
    for x in range(0, 60, 5):
        frame = renderer.render(black, DriveState(x / 5.0, speed_mps=5.0, pose=(float(x), 0.0, 0.0)))
    def drawn(image: np.ndarray, colour) -> bool:  # anti-aliased lines: near the colour is enough
        return bool((np.abs(image[:120, 280:].astype(int) - colour).max(axis=2) < 50).any())

    for colour in (CAR_COLOUR, PATH_COLOUR, ROUTE_COLOUR):
        assert drawn(frame, colour), colour
    assert not frame[150:].any()  # no segmentation given: the camera image below the sky band is untouched
    broken = renderer.render(black, DriveState(2.4, pose=(math.nan, 0.0, 0.0)))  # a broken odometry message
    assert len(renderer.path) == 12 and not drawn(broken, CAR_COLOUR) and drawn(broken, PATH_COLOUR)
