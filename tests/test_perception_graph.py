"""perception node (and perception -> control) in a real graph, with good and bad inputs."""

import shutil
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st
from diagnostic_msgs.msg import DiagnosticArray
from nav_msgs.msg import Odometry
from rcl_interfaces.msg import SetParametersResult
from rclpy.parameter import Parameter
from ros_graph import Lifecycle, Parameters
from sensor_msgs.msg import Image

from msfsu_common import topics
from msfsu_common.diagnostics import ERROR, OK, WARN
from msfsu_common.camera_geometry import depth_at_crop_pixels
from msfsu_common.image_codec import ENCODINGS, decode_depth, decode_mono8, encode_image
from msfsu_common.node_runner import StartupError
from msfsu_control.control_node import ControlNode
from msfsu_interfaces.msg import DrivingAction, NavigationCommand, StageTimes, VehicleControl
from msfsu_perception.backends import int8_build
from msfsu_perception.deploy_files import calibration_path
from msfsu_perception.gate_verdicts import GateResult, HeldOutScores, record_gate_results
from msfsu_perception.perception_node import PerceptionNode

HEIGHT, WIDTH = 48, 64
RNG = np.random.default_rng(0)
RGB = RNG.integers(0, 255, (HEIGHT, WIDTH, 3), dtype=np.uint8)
DEPTH_M = RNG.uniform(1.0, 60.0, (HEIGHT, WIDTH)).astype(np.float32)


def image(stamp_ns: int, pixels: np.ndarray, pixel_encoding: str, **overrides) -> Image:
    msg = Image(**{**encode_image(pixels, pixel_encoding), **overrides})
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(stamp_ns, 1_000_000_000)
    msg.header.frame_id = "camera_front"
    return msg


def rgb_image(stamp_ns: int, encoding: str = "rgb8") -> Image:
    pixels = {"rgb8": RGB, "bgr8": RGB[..., ::-1], "bgra8": np.dstack([RGB[..., ::-1], np.full(RGB.shape[:2], 255, np.uint8)])}
    return image(stamp_ns, pixels[encoding], encoding)


def depth_image(stamp_ns: int, encoding: str = "32FC1", depth: np.ndarray = DEPTH_M) -> Image:
    if encoding == "16UC1":
        return image(stamp_ns, (depth * 1000).astype(np.uint16), encoding)
    return image(stamp_ns, depth, encoding)


def stamp_of(msg) -> int:
    return msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec


class Perception:
    """A perception node in the graph, configured and activated through its lifecycle services (as the launcher and
    `ros2 lifecycle set` do), plus what it publishes."""

    def __init__(self, graph, checkpoint: Path, **parameters):
        overrides = [Parameter("checkpoint", value=str(checkpoint)), Parameter("diagnostics_period", value=0.1)]
        self.node = graph.add(PerceptionNode(overrides + [Parameter(k, value=v) for k, v in parameters.items()],
                                             autostart=False))
        self.graph = graph
        self.lifecycle = Lifecycle(graph, "perception")
        assert self.lifecycle.set("configure") and self.lifecycle.set("activate")
        self.actions = graph.probe.collect(DrivingAction, topics.DRIVING_ACTION)
        self.segmentations = graph.probe.collect(Image, topics.SEGMENTATION)
        self.diagnostics = graph.probe.collect(DiagnosticArray, topics.DIAGNOSTICS)

    def send(self, rgb: Image | None, depth: Image | None) -> None:
        if rgb is not None:
            self.graph.probe.publish(topics.RGB, rgb)
        if depth is not None:
            self.graph.probe.publish(topics.DEPTH, depth)

    def action_for(self, stamp_ns: int, timeout: float = 10.0) -> DrivingAction | None:
        found = self.graph.wait_for(lambda: any(stamp_of(a) == stamp_ns for a in self.actions), timeout)
        return next((a for a in self.actions if stamp_of(a) == stamp_ns), None) if found else None

    def diagnostic_value(self, key: str) -> str | None:
        for array in reversed(self.diagnostics):
            for value in array.status[0].values:
                if value.key == key:
                    return value.value
        return None


@pytest.mark.parametrize("rgb_encoding", ["rgb8", "bgr8", "bgra8"])
@pytest.mark.parametrize("depth_encoding", ["32FC1", "16UC1"])
def test_frame_pair_gives_action_and_segmentation_with_frame_stamp(graph, tiny_checkpoint, rgb_encoding, depth_encoding):
    perception = Perception(graph, tiny_checkpoint)
    stamp = 5_000_000_000
    perception.send(rgb_image(stamp, rgb_encoding), depth_image(stamp, depth_encoding))
    action = perception.action_for(stamp)
    assert action is not None
    assert -1.0 <= action.steer <= 1.0 and action.target_speed >= 0.0 and action.command == 4
    assert graph.wait_for(lambda: any(stamp_of(s) == stamp for s in perception.segmentations))
    segmentation = next(s for s in perception.segmentations if stamp_of(s) == stamp)
    assert (segmentation.encoding, segmentation.height, segmentation.width) == ("mono8", 64, 64)
    assert segmentation.header.frame_id == "camera_front"
    assert decode_mono8(segmentation).max() < 5


def test_for_the_brake_the_depth_at_each_segmentation_pixel_comes_with_the_frames_stamp(graph, tiny_checkpoint):
    """Something subscribes to the segmentation's depth (the aeb node): perception sends the camera's depth at the
    centre of each segmentation pixel (its crop: the top half gone), the segmentation's size, the frame's stamp."""
    samples = graph.probe.collect(Image, topics.SEGMENTATION_DEPTH)
    perception = Perception(graph, tiny_checkpoint)
    stamp = 6_000_000_000
    perception.send(rgb_image(stamp), depth_image(stamp))
    assert perception.action_for(stamp) is not None
    assert graph.wait_for(lambda: any(stamp_of(s) == stamp for s in samples))
    sent = decode_depth(next(s for s in samples if stamp_of(s) == stamp))
    assert sent.shape == (64, 64)  # the segmentation's
    crop = perception.node.model.preprocess.crop_top_fraction
    np.testing.assert_array_equal(sent, depth_at_crop_pixels(DEPTH_M, crop, (64, 64)))
    assert crop > 0 and sent.min() >= DEPTH_M[int(HEIGHT * crop):].min()  # only rows of the crop


def test_the_overlay_is_the_segmentation_over_the_networks_input_at_its_size(graph, tiny_checkpoint):
    """The camera is 64x48, the network's input 64x64: segmentation and overlay come at the network's size."""
    perception = Perception(graph, tiny_checkpoint, publish_overlay=True)
    overlays = graph.probe.collect(Image, topics.SEGMENTATION_OVERLAY)
    stamp = 7_000_000_000
    perception.send(rgb_image(stamp), depth_image(stamp))
    assert graph.wait_for(lambda: any(stamp_of(o) == stamp for o in overlays))
    overlay = next(o for o in overlays if stamp_of(o) == stamp)
    segmentation = next(s for s in perception.segmentations if stamp_of(s) == stamp)
    assert (HEIGHT, WIDTH) == (48, 64) and (overlay.encoding, overlay.height, overlay.width) == ("rgb8", 64, 64)
    assert (segmentation.height, segmentation.width) == (overlay.height, overlay.width)


def test_same_input_in_every_encoding_gives_the_same_action(graph, tiny_checkpoint):
    perception = Perception(graph, tiny_checkpoint)
    steers = []
    for index, (rgb_encoding, depth_encoding) in enumerate([("rgb8", "32FC1"), ("bgra8", "32FC1"), ("bgr8", "32FC1")]):
        stamp = (index + 1) * 1_000_000_000
        perception.send(rgb_image(stamp, rgb_encoding), depth_image(stamp, depth_encoding))
        steers.append(perception.action_for(stamp).steer)
    assert steers[0] == steers[1] == steers[2]


def test_navigation_command_selects_the_branch_and_unknown_command_is_ignored(graph, tiny_checkpoint):
    perception = Perception(graph, tiny_checkpoint)
    graph.probe.publish(topics.NAVIGATION_COMMAND, NavigationCommand(command=NavigationCommand.LEFT))
    assert graph.wait_for(lambda: perception.node.scheduler.command.name == "LEFT")
    graph.probe.publish(topics.NAVIGATION_COMMAND, NavigationCommand(command=17))
    assert graph.wait_for(lambda: perception.node.stats.dropped["bad_command"] == 1)
    perception.send(rgb_image(10**9), depth_image(10**9))
    assert perception.action_for(10**9).command == NavigationCommand.LEFT


def command(option: int, stamp_ns: int) -> NavigationCommand:
    msg = NavigationCommand(command=option)
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(stamp_ns, 1_000_000_000)
    return msg


def test_command_wait_holds_a_frame_until_the_command_stamped_for_it(graph, tiny_checkpoint):
    """Lockstep (the agent profile): the route node answers each frame's odometry with a command stamped like it; the
    frame is inferred with that command however late it comes, an older one does not release it."""
    perception = Perception(graph, tiny_checkpoint, command_wait=5.0)
    stamp = 2_000_000_000
    perception.send(rgb_image(stamp), depth_image(stamp))
    graph.probe.publish(topics.NAVIGATION_COMMAND, command(NavigationCommand.RIGHT, stamp - 100_000_000))
    assert graph.wait_for(lambda: perception.node.scheduler.command.name == "RIGHT")
    assert perception.action_for(stamp, timeout=0.5) is None  # held: its command is not there yet
    graph.probe.publish(topics.NAVIGATION_COMMAND, command(NavigationCommand.LEFT, stamp))
    assert perception.action_for(stamp).command == NavigationCommand.LEFT
    assert perception.node.scheduler.command_timeouts == 0


def test_command_wait_serves_a_frame_with_the_latest_command_when_its_own_does_not_come(graph, tiny_checkpoint):
    perception = Perception(graph, tiny_checkpoint, command_wait=0.2)
    perception.send(rgb_image(3_000_000_000), depth_image(3_000_000_000))
    action = perception.action_for(3_000_000_000, timeout=5.0)
    assert action is not None and action.command == NavigationCommand.LANE_FOLLOW
    assert perception.node.scheduler.command_timeouts == 1
    assert graph.wait_for(lambda: perception.diagnostic_value("command_wait_timeouts") == "1")


def test_stamps_beyond_slop_are_not_paired(graph, tiny_checkpoint):
    perception = Perception(graph, tiny_checkpoint, sync_slop=0.02)
    perception.send(rgb_image(1_000_000_000), depth_image(1_100_000_000))
    assert perception.action_for(1_000_000_000, timeout=1.0) is None
    assert perception.action_for(1_100_000_000, timeout=0.1) is None


BAD_INPUTS = {
    "wrong_encoding": (lambda s: (image(s, RGB, "rgb8", encoding="yuv422"), depth_image(s)), "dropped_bad_rgb"),
    "wrong_step": (lambda s: (image(s, RGB, "rgb8", step=10), depth_image(s)), "dropped_bad_rgb"),
    "truncated_data": (lambda s: (rgb_image(s), image(s, DEPTH_M, "32FC1", data=DEPTH_M.tobytes()[:-7])),
                       "dropped_bad_depth"),
    "size_mismatch": (lambda s: (rgb_image(s), depth_image(s, depth=DEPTH_M[:20, :30].copy())), "dropped_bad_frame"),
    "nan_depth": (lambda s: (rgb_image(s), depth_image(s, depth=np.full_like(DEPTH_M, np.nan))), "dropped_bad_frame"),
    "inf_depth": (lambda s: (rgb_image(s), depth_image(s, depth=np.full_like(DEPTH_M, -np.inf))), "dropped_bad_frame"),
    "missing_depth_partner": (lambda s: (rgb_image(s), None), None),
}


@pytest.mark.parametrize("case", sorted(BAD_INPUTS))
def test_bad_input_is_reported_and_the_next_good_frame_is_served(graph, tiny_checkpoint, case):
    perception = Perception(graph, tiny_checkpoint, sync_queue_size=2)
    make_bad, diagnostic_key = BAD_INPUTS[case]
    bad_stamp, good_stamp = 1_000_000_000, 2_000_000_000
    perception.send(*make_bad(bad_stamp))
    if diagnostic_key is not None:
        assert graph.wait_for(lambda: perception.diagnostic_value(diagnostic_key) == "1"), perception.node.stats.dropped
    perception.send(rgb_image(good_stamp), depth_image(good_stamp))
    assert perception.action_for(good_stamp) is not None
    assert perception.action_for(bad_stamp, timeout=0.1) is None
    if case == "missing_depth_partner":  # the lone frame is dropped once the next pair supersedes it
        assert graph.wait_for(lambda: perception.diagnostic_value("dropped_unpaired_a") == "1")


def test_a_real_depth_cameras_invalid_pixels_keep_the_frame_and_are_counted(graph, tiny_checkpoint):
    """RealSense/OpenNI conventions under the default parameters: 16UC1 zeros, a 3 % NaN patch in 32FC1."""
    perception = Perception(graph, tiny_checkpoint)
    patched = DEPTH_M.copy()
    patched[30:36, 40:56] = np.nan  # 96 of 3072 pixels: 3.1 %
    millimetres = (DEPTH_M * 1000).astype(np.uint16)
    millimetres[::2, ::2] = 0  # a quarter of the pixels without a return
    perception.send(rgb_image(1_000_000_000), image(1_000_000_000, patched, "32FC1"))
    assert perception.action_for(1_000_000_000) is not None
    perception.send(rgb_image(2_000_000_000), image(2_000_000_000, millimetres, "16UC1"))
    assert perception.action_for(2_000_000_000) is not None
    assert graph.wait_for(lambda: perception.diagnostic_value("depth_frames_with_invalid_pixels") == "2")
    assert float(perception.diagnostic_value("depth_invalid_share_max")) == 0.25
    assert not perception.node.stats.dropped


def test_command_wait_set_to_0_live_serves_the_held_frame_at_once(graph, tiny_checkpoint):
    perception = Perception(graph, tiny_checkpoint, command_wait=5.0)
    parameters = Parameters(graph, "perception")
    perception.send(rgb_image(2_000_000_000), depth_image(2_000_000_000))
    assert perception.action_for(2_000_000_000, timeout=0.5) is None  # held: no command is stamped for it
    assert parameters.set_each(command_wait=0.0) == [SetParametersResult(successful=True)]
    assert perception.action_for(2_000_000_000, timeout=2.0).command == NavigationCommand.LANE_FOLLOW  # not after 5 s
    assert perception.node.scheduler.command_timeouts == 0


def test_max_invalid_depth_fraction_set_live_drops_the_next_such_frame_and_the_checkpoint_is_read_only(
        graph, tiny_checkpoint):
    perception = Perception(graph, tiny_checkpoint)
    parameters = Parameters(graph, "perception")
    holed = DEPTH_M.copy()
    holed[:14] = np.nan  # 14 of 48 rows: 29 % of the pixels
    perception.send(rgb_image(1_000_000_000), image(1_000_000_000, holed, "32FC1"))
    assert perception.action_for(1_000_000_000) is not None  # under the default 0.5
    assert parameters.set_each(max_invalid_depth_fraction=0.2, checkpoint="other.pt") == [
        SetParametersResult(successful=True),
        SetParametersResult(successful=False, reason="Trying to set a read-only parameter: checkpoint.")]
    perception.send(rgb_image(2_000_000_000), image(2_000_000_000, holed, "32FC1"))
    assert graph.wait_for(lambda: perception.node.stats.dropped["bad_frame"] == 1)
    assert perception.action_for(2_000_000_000, timeout=0.5) is None
    assert parameters.get("max_invalid_depth_fraction", "checkpoint") == [0.2, str(tiny_checkpoint)]


def test_out_of_order_and_duplicate_stamps_are_dropped(graph, tiny_checkpoint):
    perception = Perception(graph, tiny_checkpoint)
    perception.send(rgb_image(3_000_000_000), depth_image(3_000_000_000))
    assert perception.action_for(3_000_000_000) is not None
    perception.send(rgb_image(3_000_000_000), None)  # duplicate
    perception.send(rgb_image(2_000_000_000), depth_image(2_000_000_000))  # out of order
    assert graph.wait_for(lambda: perception.diagnostic_value("dropped_duplicate_stamp_a") == "1")
    assert graph.wait_for(lambda: perception.diagnostic_value("dropped_out_of_order_stamp_a") == "1")
    perception.send(rgb_image(4_000_000_000), depth_image(4_000_000_000))
    assert perception.action_for(4_000_000_000) is not None
    assert len(perception.actions) == 2


def test_slow_inference_skips_to_the_newest_frame_without_backlog(graph, tiny_checkpoint):
    perception = Perception(graph, tiny_checkpoint, sensor_queue_depth=50)  # DDS keeps all: skips are ours
    stamps = [(i + 1) * 100_000_000 for i in range(15)]
    for stamp in stamps:  # a burst far faster than inference
        perception.send(rgb_image(stamp), depth_image(stamp))
    assert perception.action_for(stamps[-1]) is not None  # the newest frame is always served
    node = perception.node
    assert graph.wait_for(lambda: node.stats.processed + node.scheduler.skipped == len(stamps)), (node.stats.processed, node.scheduler.skipped, node.synchronizer.dropped)
    assert node.scheduler.skipped > 0 and len(perception.actions) == node.stats.processed
    assert [stamp_of(a) for a in perception.actions] == sorted(stamp_of(a) for a in perception.actions)


def test_perception_to_control_chain(graph, tiny_checkpoint):
    perception = Perception(graph, tiny_checkpoint, publish_stage_times=True)
    graph.add(ControlNode([Parameter("publish_stage_times", value=True)]))
    controls = graph.probe.collect(VehicleControl, topics.VEHICLE_CONTROL)
    stage_times = graph.probe.collect(StageTimes, topics.STAGE_TIMES)
    odometry = Odometry()
    odometry.twist.twist.linear.x = 3.0
    graph.probe.publish(topics.ODOMETRY, odometry)
    for index in range(3):
        stamp = (index + 1) * 100_000_000
        perception.send(rgb_image(stamp), depth_image(stamp))
        assert perception.action_for(stamp) is not None
    assert graph.wait_for(lambda: len(controls) >= 3)
    for control in controls:
        assert 0.0 <= control.throttle <= 1.0 and 0.0 <= control.brake <= 1.0 and -1.0 <= control.steer <= 1.0
    # every frame's path through both nodes in wall-clock order: the latency trace the soak reads
    assert graph.wait_for(lambda: len(stage_times) == 6)
    order = {"perception": ["rgb_dds", "rgb_taken", "paired", "inference_start", "preprocessed", "inferred",
                            "action_published"],
             "control": ["action_dds", "action_taken", "control_published"]}
    for index in range(3):
        stamp = (index + 1) * 100_000_000
        traces = {t.header.frame_id: dict(zip(t.stages, t.times_ns)) for t in stage_times if stamp_of(t) == stamp}
        assert set(traces) == set(order)
        assert traces["perception"]["depth_dds"] <= traces["perception"]["depth_taken"] <= traces["perception"]["paired"]
        for node, stages in order.items():
            times = [traces[node][stage] for stage in stages]
            assert times == sorted(times), traces
        # a publish call returns after the middleware handed the message on: the receiver's time lies in between
        assert traces["perception"]["inferred"] <= traces["control"]["action_dds"]


def test_missing_checkpoint_fails_at_start_up(graph, tmp_path):
    with pytest.raises(StartupError, match="does not exist"):
        PerceptionNode([Parameter("checkpoint", value=str(tmp_path / "missing.pt"))])
    with pytest.raises(StartupError, match="'checkpoint' is required"):
        PerceptionNode()


# --- the lifecycle, driven through the lifecycle_msgs services as `ros2 lifecycle set` drives them -----------------
def perception_status(diagnostics: list[DiagnosticArray]):
    """The newest `msfsu/perception` status (the node's parameter status shares /diagnostics)."""
    return next((status for array in reversed(diagnostics) for status in array.status
                 if status.name == "msfsu/perception"), None)


def reports(graph, diagnostics, state: str, message: str, level: bytes) -> bool:
    """Whether the node's status comes to say `state` (value lifecycle_state), `message` (start) at `level`."""
    def said() -> bool:
        status = perception_status(diagnostics)
        return (status is not None and {v.key: v.value for v in status.values}.get("lifecycle_state") == state
                and status.message.startswith(message) and status.level == level)
    return graph.wait_for(said, 10.0)


def served(graph, perception_node, stamp: int) -> DrivingAction | None:
    graph.probe.publish(topics.RGB, rgb_image(stamp))
    graph.probe.publish(topics.DEPTH, depth_image(stamp))
    actions = graph.probe.received[topics.DRIVING_ACTION]
    found = graph.wait_for(lambda: any(stamp_of(a) == stamp for a in actions))
    return next(a for a in actions if stamp_of(a) == stamp) if found else None


def test_each_transition_does_what_its_state_says_driven_through_the_lifecycle_services(graph, tiny_checkpoint):
    node = graph.add(PerceptionNode([Parameter("checkpoint", value=str(tiny_checkpoint)),
                                     Parameter("diagnostics_period", value=0.1)], autostart=False))
    graph.probe.collect(DrivingAction, topics.DRIVING_ACTION)
    diagnostics = graph.probe.collect(DiagnosticArray, topics.DIAGNOSTICS)
    lifecycle = Lifecycle(graph, "perception")
    probe = graph.probe

    def subscribed() -> bool:
        return probe.count_subscribers(topics.RGB) == 1 and probe.count_subscribers(topics.DEPTH) == 1

    assert lifecycle.state() == "unconfigured" and node.model is None
    assert reports(graph, diagnostics, "unconfigured", "unconfigured: no network loaded", WARN)
    assert probe.count_subscribers(topics.RGB) == 0 and probe.count_publishers(topics.DRIVING_ACTION) == 0

    assert lifecycle.set("configure") and lifecycle.state() == "inactive" and node.model is not None
    assert reports(graph, diagnostics, "inactive", "inactive: configured, not subscribed", OK)
    assert graph.wait_for(lambda: probe.count_publishers(topics.DRIVING_ACTION) == 1)
    assert probe.count_subscribers(topics.RGB) == 0  # inactive: no camera frame reaches it

    assert lifecycle.set("activate") and lifecycle.state() == "active"
    assert graph.wait_for(subscribed)
    assert served(graph, node, 1_000_000_000) is not None
    assert reports(graph, diagnostics, "active", "running", OK)

    assert lifecycle.set("deactivate") and lifecycle.state() == "inactive"
    assert graph.wait_for(lambda: probe.count_subscribers(topics.RGB) == 0) and node.model is not None
    assert not lifecycle.set("configure")  # not a transition of inactive: refused, nothing changes
    assert lifecycle.state() == "inactive"

    assert lifecycle.set("cleanup") and lifecycle.state() == "unconfigured" and node.model is None
    assert graph.wait_for(lambda: probe.count_publishers(topics.DRIVING_ACTION) == 0)

    assert lifecycle.set("configure") and lifecycle.set("activate")  # up again, a new stream: earlier stamps too
    assert graph.wait_for(subscribed) and served(graph, node, 500_000_000) is not None

    assert lifecycle.set("shutdown") and lifecycle.state() == "finalized" and node.model is None
    assert graph.wait_for(lambda: probe.count_subscribers(topics.RGB) == 0)
    assert reports(graph, diagnostics, "finalized", "finalized: no network loaded", WARN)


def test_a_network_that_cannot_be_loaded_leaves_the_node_unconfigured_with_the_reason(graph, tmp_path):
    missing = tmp_path / "missing.pt"
    node = graph.add(PerceptionNode([Parameter("checkpoint", value=str(missing)),
                                     Parameter("diagnostics_period", value=0.1)], autostart=False))
    diagnostics = graph.probe.collect(DiagnosticArray, topics.DIAGNOSTICS)
    lifecycle = Lifecycle(graph, "perception")
    assert not lifecycle.set("configure")
    assert lifecycle.state() == "unconfigured" and node.model is None
    assert reports(graph, diagnostics, "unconfigured",
                   f"unconfigured: configure failed: cannot use checkpoint '{missing}': ", ERROR)
    assert "does not exist" in perception_status(diagnostics).message


def test_a_lifecycle_node_stopped_by_sigterm_goes_through_its_shutdown_transition(graph, tiny_checkpoint, tmp_path):
    """The executable starts unconfigured; brought up through its services, SIGTERM ends it through shutdown."""
    log = tmp_path / "perception.log"
    with log.open("w") as output:
        process = subprocess.Popen([str(Path(sys.executable).parent / "perception"), "--ros-args", "-p",
                                    f"checkpoint:={tiny_checkpoint}", "-p", "backend:=torch"],
                                   stdout=output, stderr=subprocess.STDOUT)
    try:
        lifecycle = Lifecycle(graph, "perception")
        assert lifecycle.state() == "unconfigured"
        assert lifecycle.set("configure") and lifecycle.set("activate"), log.read_text()
        process.send_signal(signal.SIGTERM)
        assert process.wait(timeout=30) == 0, log.read_text()
    finally:
        if process.poll() is None:
            process.kill()
    lines = log.read_text().splitlines()
    assert [line.split("]: ")[1] for line in lines if "[perception]: " in line][-2:] == [
        "active: subscribed to the command and the cameras", "finalized"]


def test_incompatible_checkpoint_ends_the_launch_non_zero_with_a_clear_message(tmp_path):
    """The launcher configures the perception process (as it does by default); the reason is the node's one line."""
    bad = tmp_path / "bad.pt"
    bad.write_bytes(b"not a checkpoint")
    profile = tmp_path / "perception.yaml"
    profile.write_text(yaml.safe_dump({"nodes": [{"name": "perception", "package": "msfsu_perception",
                                                  "executable": "perception", "lifecycle": True,
                                                  "parameters": {"checkpoint": str(bad)}}]}))
    result = subprocess.run([sys.executable, "-m", "msfsu_bringup", str(profile)], capture_output=True, text=True,
                            timeout=120)
    assert result.returncode == 1, result.stdout + result.stderr
    output = result.stdout + result.stderr
    assert "cannot configure: cannot use checkpoint" in output and "corrupt" in output
    assert "[bringup] perception did not configure (its log says why): stopping the launch" in output
    assert "Traceback" not in output


def gated_copy(checkpoint: Path, directory: Path) -> Path:
    """A copy of `checkpoint` whose OpenVINO bf16 and int8 passed the accuracy gate (calibration frames beside it)."""
    path = directory / "gated.pt"
    shutil.copyfile(checkpoint, path)
    same = HeldOutScores(steer_mae=0.1, mean_iou=0.5)
    rng = np.random.default_rng(0)  # present: int8 is a candidate (its verdict names these frames)
    np.savez(calibration_path(path), rgb=rng.integers(0, 256, (2, 3, 64, 64), np.uint8),
             depth=rng.random((2, 1, 64, 64)).astype(np.float16), command_index=np.arange(2))
    build = int8_build(path).to_dict()
    record_gate_results(path, [GateResult("openvino", precision, 10, same, same, 0.0, 1.0,
                                          build=build if precision == "int8" else None) for precision in ("bf16", "int8")])
    return path


def test_default_precision_falls_back_to_fp32_on_a_cpu_without_bf16_and_int8(graph, tiny_checkpoint, tmp_path,
                                                                             cpu_reports, caplog):
    checkpoint = gated_copy(tiny_checkpoint, tmp_path)
    cpu_reports("FP32", "WINOGRAD", "BIN")  # e.g. a laptop or an older server: no avx512_bf16 / AMX, no int8 kernels
    perception = Perception(graph, checkpoint)  # the defaults: backend auto, precision auto
    assert (perception.node.model.backend, perception.node.model.precision) == ("openvino", "fp32")
    assert "bf16 passed the accuracy gate" in caplog.text and "int8 passed the accuracy gate" in caplog.text
    perception.send(rgb_image(10**9), depth_image(10**9))
    assert perception.action_for(10**9) is not None


def test_explicit_precision_the_cpu_lacks_is_refused_with_the_reason(graph, tiny_checkpoint, cpu_reports):
    cpu_reports("FP32", "INT8")
    for backend in ("openvino", "torch"):
        with pytest.raises(StartupError,
                           match=f"on {backend}/bf16 \\(device auto\\): this CPU cannot run bf16 .*avx512_bf16 or AMX"):
            PerceptionNode([Parameter("checkpoint", value=str(tiny_checkpoint)), Parameter("backend", value=backend),
                            Parameter("precision", value="bf16")])


@pytest.mark.skipif(torch.cuda.is_available(), reason="this machine has a CUDA device")
def test_device_cuda_without_a_gpu_is_refused_in_one_line(graph, tiny_checkpoint):
    with pytest.raises(StartupError, match=r"\(device cuda\): device cuda: this torch .* is a CPU build: install the CUDA "
                                           r"build with `make setup TORCH=cuda`"):
        PerceptionNode([Parameter("checkpoint", value=str(tiny_checkpoint)), Parameter("device", value="cuda")])


LATEST_FUZZED_SEC = 2**31 - 10  # the good frame after the fuzz must be newer than every fuzzed one


@st.composite
def sensor_messages(draw) -> tuple[Image, Image, NavigationCommand]:
    """An RGB and a depth message sharing one (any int32/uint32) stamp, each field possibly hostile."""
    height, width = draw(st.integers(1, 12)), draw(st.integers(1, 12))
    sec, nanosec = draw(st.integers(-2**31, LATEST_FUZZED_SEC)), draw(st.integers(0, 2**32 - 1))

    def message(encodings) -> Image:
        encoding = draw(st.sampled_from(encodings))
        dtype, channels = ENCODINGS.get(encoding, (np.dtype(np.uint8), 1))
        step = width * channels * dtype.itemsize + draw(st.sampled_from([0, 0, 0, 1, -1]))
        size = max(step, 0) * height + draw(st.sampled_from([0, 0, 0, 3, -2]))
        msg = Image(height=height, width=width, encoding=encoding, is_bigendian=draw(st.integers(0, 1)),
                    step=max(step, 0), data=draw(st.binary(min_size=max(size, 0), max_size=max(size, 0))))
        msg.header.stamp.sec, msg.header.stamp.nanosec = sec, nanosec
        return msg

    command = NavigationCommand(command=draw(st.integers(0, 255)))
    command.header.stamp.sec = draw(st.integers(-2**31, 2**31 - 1))
    return message(["rgb8", "bgr8", "bgra8", "rgba8", "mono8", "yuv422"]), message(["32FC1", "16UC1", "mono8"]), command


def test_perception_and_control_nodes_survive_any_sensor_and_command_values(graph, tiny_checkpoint):
    """Fuzz (hypothesis) through the nodes' own callbacks: only counted drops, never an exception."""
    perception = Perception(graph, tiny_checkpoint, sync_queue_size=3)
    control = graph.add(ControlNode())
    node = perception.node

    @settings(max_examples=40, deadline=None)
    @given(sensor_messages(), st.floats(width=32), st.floats(width=32), st.integers(-2**31, 2**31 - 1))
    def feed(sensors, steer, target_speed, sec):
        rgb, depth, command = sensors
        node.on_command(command)
        node.on_rgb(rgb)
        node.on_depth(depth)
        action = DrivingAction(steer=steer, target_speed=target_speed, command=command.command)
        action.header.stamp.sec = sec
        odometry = Odometry()
        odometry.twist.twist.linear.x = float(abs(target_speed))
        control.on_odometry(odometry)
        control.on_action(action)

    feed()
    graph.probe.publish(topics.NAVIGATION_COMMAND, NavigationCommand(command=NavigationCommand.LANE_FOLLOW))
    assert graph.wait_for(lambda: node.scheduler.command.name == "LANE_FOLLOW")
    stamp = (2**31 - 1) * 1_000_000_000  # later than any fuzzed frame (nanosec < 4.3 s): not out of order
    perception.send(rgb_image(stamp), depth_image(stamp))
    assert perception.action_for(stamp) is not None
