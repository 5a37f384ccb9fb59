"""The aeb node in a real graph: the network's action in, the action on to the control out (same stamp), its
interventions and diagnostics, the fail-safe rule for a frame without segmentation, and live parameters."""

import math
import signal
import subprocess
import sys
from dataclasses import fields

import numpy as np
import pytest
from diagnostic_msgs.msg import DiagnosticArray
from nav_msgs.msg import Odometry
from rclpy.parameter import Parameter
from sensor_msgs.msg import Image

from msfsu_common import topics
from msfsu_common.camera_geometry import FrontCamera, depth_at_crop_pixels
from msfsu_common.image_codec import encode_image
from msfsu_common.road_option import RoadOption
from msfsu_common.semantic_classes import SemanticClass
from msfsu_control.aeb_node import AebCamera, AebNode, camera_parameters
from msfsu_interfaces.msg import AebIntervention, DrivingAction, StageTimes, VehicleControl
from msfsu_perception.preprocessing import PreprocessConfig
from msfsu_sim.sim_types import SimConfig
from ros_graph import Parameters

WIDTH, HEIGHT, SEG = 400, 300, 128  # the simulator's camera and the shipped network's segmentation
CAMERA = [Parameter("camera_width_px", value=WIDTH), Parameter("camera_height_px", value=HEIGHT)]


def depth_samples(depth: np.ndarray, sec: int, nanosec: int = 0) -> Image:
    """The camera's depth at the segmentation's pixels, as perception publishes it (topics.SEGMENTATION_DEPTH)."""
    return stamped(Image(**encode_image(depth_at_crop_pixels(depth, 0.5, (SEG, SEG)), "32FC1")), sec, nanosec)


def stamped(msg, sec: int, nanosec: int = 0):
    msg.header.stamp.sec, msg.header.stamp.nanosec = sec, nanosec
    return msg


def frame(obstacle: bool) -> tuple[np.ndarray, np.ndarray]:
    """(segmentation, depth): road everywhere at 60 m, and with `obstacle` a patch of vehicle_or_pedestrian in the
    middle of the image just below the horizon at 3 m depth: about 1.7 m in front of the bumper, 0.5-2 m high."""
    depth = np.full((HEIGHT, WIDTH), 60.0, np.float32)
    segmentation = np.zeros((SEG, SEG), np.uint8)
    if obstacle:
        depth[150:200, 180:220] = 3.0
        segmentation[:40, 60:68] = SemanticClass.VEHICLE_OR_PEDESTRIAN
    return segmentation, depth


def publish_frame(graph, sec: int, obstacle: bool | None, target: float = 5.0, x: float = 0.0) -> None:
    """The frame's odometry (the car at `x`) and depth samples, its segmentation (None: none) and the network's action."""
    odometry = Odometry()
    odometry.twist.twist.linear.x = 2.0
    odometry.pose.pose.position.x = x
    graph.probe.publish(topics.ODOMETRY, stamped(odometry, sec))
    segmentation, depth = frame(bool(obstacle))
    graph.probe.publish(topics.SEGMENTATION_DEPTH, depth_samples(depth, sec))
    if obstacle is not None:
        graph.probe.publish(topics.SEGMENTATION, stamped(Image(**encode_image(segmentation, "mono8")), sec))
    graph.probe.publish(topics.NETWORK_ACTION, stamped(
        DrivingAction(steer=0.1, target_speed=target, command=int(RoadOption.LANE_FOLLOW)), sec))


def sent_on(actions, sec: int):
    return next((a for a in actions if a.header.stamp.sec == sec), None)


def test_the_brakes_camera_defaults_are_the_simulators_front_camera_and_the_shipped_crop():
    """The benchmark and the sim profile run the brake on its defaults: they must describe the camera the simulator
    renders (its size, lens and pitch) and the shipped networks' crop."""
    camera, sim = AebCamera(), SimConfig()
    assert (camera.camera_width_px, camera.camera_height_px) == (sim.width, sim.height)
    assert (camera.camera_fov_deg, camera.camera_pitch_deg) == (sim.mount.fov_deg, sim.mount.pitch_deg)
    assert (camera.camera_forward_m, camera.camera_right_m) == (sim.mount.y, sim.mount.x)
    assert camera.crop_top_fraction == PreprocessConfig().crop_top_fraction


def test_a_bags_camera_becomes_the_brakes_view_through_its_parameters(graph):
    """What msfsu-eval-bag and the profiles' aeb_camera give the node (camera_parameters of a bag's camera) names its
    declared camera parameters, and the node places pixels with that camera and the crop."""
    sim = FrontCamera(400, 300, 80.0, 1.0, 0.0, 2.095, -2.0)
    defaults = AebCamera()
    assert camera_parameters(sim) == {name: getattr(defaults, name) for name in camera_parameters(sim)}
    assert set(camera_parameters(sim)) == {field.name for field in fields(AebCamera)} - {"crop_top_fraction"}
    carla = FrontCamera(800, 600, 90.0, 2.0, 0.0, 2.0, 0.0)  # docs/carla.md's recipe
    node = graph.add(AebNode([Parameter(name, value=value) for name, value in camera_parameters(carla).items()]))
    assert node.view == carla.view(defaults.crop_top_fraction, 0, 0)


def test_the_brake_overrides_the_target_speed_reports_it_and_lets_go(graph):
    node = graph.add(AebNode([Parameter("release_s", value=0.0), *CAMERA]))
    actions = graph.probe.collect(DrivingAction, topics.DRIVING_ACTION)
    interventions = graph.probe.collect(AebIntervention, topics.AEB_INTERVENTION)
    publish_frame(graph, 10, obstacle=True)
    assert graph.wait_for(lambda: sent_on(actions, 10) is not None)
    braked = sent_on(actions, 10)
    assert (braked.target_speed, braked.steer, braked.command) == (0.0, pytest.approx(0.1), int(RoadOption.LANE_FOLLOW))
    assert graph.wait_for(lambda: interventions)
    (report,) = interventions
    assert (report.header.stamp.sec, report.decision, report.target_speed_in, report.target_speed_out) == (
        10, "brake", 5.0, 0.0)
    assert report.reason == "obstacle within the stop gap" and 1.0 < report.gap_m < 2.0 and report.obstacle_pixels > 4
    publish_frame(graph, 11, obstacle=False)
    assert graph.wait_for(lambda: sent_on(actions, 11) is not None)
    assert sent_on(actions, 11).target_speed == 5.0  # the corridor clear: the network's target passes
    assert graph.wait_for(lambda: len(interventions) == 2) and interventions[1].decision == "none"  # let go, once
    publish_frame(graph, 12, obstacle=False)
    assert graph.wait_for(lambda: sent_on(actions, 12) is not None)
    assert len(interventions) == 2
    assert node.interventions == 1


def test_with_stage_times_it_traces_each_action_from_its_arrival_to_its_publish(graph):
    graph.add(AebNode([Parameter("publish_stage_times", value=True), *CAMERA]))
    actions = graph.probe.collect(DrivingAction, topics.DRIVING_ACTION)
    traces = graph.probe.collect(StageTimes, topics.STAGE_TIMES)
    publish_frame(graph, 15, obstacle=False)
    assert graph.wait_for(lambda: sent_on(actions, 15) is not None and traces)
    (trace,) = traces
    marks = dict(zip(trace.stages, trace.times_ns))
    assert (trace.header.stamp.sec, trace.header.frame_id) == (15, "aeb")
    assert (marks["network_action_sent"] <= marks["network_action_dds"] <= marks["network_action_taken"]
            <= marks["aeb_inputs_ready"] <= marks["aeb_published"])


def test_an_action_without_its_segmentation_waits_then_passes_as_a_counted_drop(graph):
    node = graph.add(AebNode([Parameter("input_wait", value=0.2), *CAMERA]))
    actions = graph.probe.collect(DrivingAction, topics.DRIVING_ACTION)
    diagnostics = graph.probe.collect(DiagnosticArray, topics.DIAGNOSTICS)
    publish_frame(graph, 20, obstacle=None)  # the perception node's segmentation of this frame never comes
    assert graph.wait_for(lambda: sent_on(actions, 20) is not None)
    assert sent_on(actions, 20).target_speed == 5.0 and node.brake.drops["no_segmentation"] == 1

    def reported():
        for array in diagnostics:
            for status in array.status:
                values = {item.key: item.value for item in status.values}
                if status.name == "msfsu/aeb" and values.get("dropped_no_segmentation") == "1":
                    return True
        return False

    assert graph.wait_for(reported, timeout=5.0)


def test_disabled_it_judges_and_reports_but_passes_the_action_and_the_switch_is_live(graph):
    graph.add(AebNode(CAMERA))
    actions = graph.probe.collect(DrivingAction, topics.DRIVING_ACTION)
    interventions = graph.probe.collect(AebIntervention, topics.AEB_INTERVENTION)
    parameters = Parameters(graph, "aeb")
    assert parameters.set_each(enabled=False)[0].successful
    publish_frame(graph, 30, obstacle=True)
    assert graph.wait_for(lambda: sent_on(actions, 30) is not None and interventions)
    assert sent_on(actions, 30).target_speed == 5.0 and interventions[0].decision == "brake"
    assert parameters.set_each(enabled=True, stop_gap_m=0.5, brake_ttc_s=0.1)[0].successful
    assert not parameters.set_each(margin_m=-1.0)[0].successful  # out of range: refused, the old value stays
    publish_frame(graph, 31, obstacle=True, target=1.0)  # 1.7 m, closing at 2 m/s: no longer within the stop gap
    assert graph.wait_for(lambda: sent_on(actions, 31) is not None)
    assert sent_on(actions, 31).target_speed == 0.0  # held: the brake lets go only after release_s (1 s)
    assert math.isclose(interventions[-1].target_speed_in, 1.0)


def test_a_new_start_resets_the_brake_so_nothing_of_one_episode_carries_into_the_next(graph):
    """Braking at the end of one episode, the brake holds for release_s of clear frames; where the car's position
    jumps (the simulator's next episode) it starts afresh: the first clear frame passes at once."""
    node = graph.add(AebNode(CAMERA))
    actions = graph.probe.collect(DrivingAction, topics.DRIVING_ACTION)
    publish_frame(graph, 40, obstacle=True)
    publish_frame(graph, 41, obstacle=False, x=0.5)  # the same episode: the brake is held
    assert graph.wait_for(lambda: sent_on(actions, 41) is not None)
    assert sent_on(actions, 40).target_speed == 0.0 and sent_on(actions, 41).target_speed == 0.0
    publish_frame(graph, 42, obstacle=False, x=250.0)  # the next episode's spawn
    assert graph.wait_for(lambda: sent_on(actions, 42) is not None)
    assert sent_on(actions, 42).target_speed == 5.0 and node.restarts == 1


def crossing_frame(column: int) -> tuple[np.ndarray, np.ndarray]:
    """A pedestrian 6 m down the optical axis whose 8 segmentation columns start at `column` (110: about 3.4 m right of
    the centre line; 84: about 1.6 m, the corridor's edge), 0.8-2 m high: (segmentation, depth)."""
    depth = np.full((HEIGHT, WIDTH), 60.0, np.float32)
    segmentation = np.zeros((SEG, SEG), np.uint8)
    segmentation[:40, column:column + 8] = SemanticClass.VEHICLE_OR_PEDESTRIAN
    depth[150:200, int(column * WIDTH / SEG):int((column + 8) * WIDTH / SEG) + 1] = 6.0
    return segmentation, depth


@pytest.mark.parametrize("predict", [False, True])
def test_with_crossing_prediction_a_pedestrian_walking_in_is_capped_for_before_the_corridor(graph, predict):
    """A pedestrian walks from 3.4 m right of the path towards it at about 1 m/s, 10 frames a second, while the car
    (its pose from the odometry, facing 90 degrees) asks for 5 m/s: with predict_crossing the brake caps the car while
    the pedestrian is still beside the corridor; without, it waits until it is in."""
    graph.add(AebNode([Parameter("predict_crossing", value=predict), *CAMERA]))
    actions = graph.probe.collect(DrivingAction, topics.DRIVING_ACTION)
    interventions = graph.probe.collect(AebIntervention, topics.AEB_INTERVENTION)
    for i, column in enumerate(range(110, 92, -2)):  # still 2.2 m or more right of the path at the last frame
        sec, nanosec = 50 + i // 10, (i % 10) * 100_000_000
        odometry = Odometry()
        odometry.twist.twist.linear.x = 1.0
        odometry.pose.pose.position.y = 0.1 * i  # facing +y: yaw 90 degrees counter-clockwise
        orientation = odometry.pose.pose.orientation
        orientation.z, orientation.w = math.sin(math.pi / 4), math.cos(math.pi / 4)
        graph.probe.publish(topics.ODOMETRY, stamped(odometry, sec, nanosec))
        segmentation, depth = crossing_frame(column)
        graph.probe.publish(topics.SEGMENTATION_DEPTH, depth_samples(depth, sec, nanosec))
        graph.probe.publish(topics.SEGMENTATION, stamped(Image(**encode_image(segmentation, "mono8")), sec, nanosec))
        graph.probe.publish(topics.NETWORK_ACTION, stamped(
            DrivingAction(steer=0.0, target_speed=5.0, command=int(RoadOption.LANE_FOLLOW)), sec, nanosec))
        assert graph.wait_for(lambda: len(actions) == i + 1)
    if predict:
        assert interventions and interventions[0].reason == "crossing into the corridor"
        assert min(a.target_speed for a in actions) < 2.0
    else:
        assert not interventions and all(a.target_speed == 5.0 for a in actions)


def test_composed_with_the_control_in_one_process_the_brake_stops_the_car(graph, tmp_path):
    """aeb_control (the aeb and control nodes, one executor, one process: msfsu_common.node_runner.run_nodes): the
    network's action in, a braking VehicleControl of the same frame out, the throttle back once the corridor is
    clear; a parameter named for one node reaches that node only; SIGINT ends the process cleanly."""
    controls = graph.probe.collect(VehicleControl, topics.VEHICLE_CONTROL)
    log = tmp_path / "aeb_control.log"
    with log.open("w") as output:
        process = subprocess.Popen(
            [sys.executable, "-m", "msfsu_control.aeb_control", "--ros-args", "-p", f"aeb:camera_width_px:={WIDTH}",
             "-p", f"aeb:camera_height_px:={HEIGHT}", "-p", "aeb:release_s:=0.0"], stdout=output,
            stderr=subprocess.STDOUT)
    try:
        publish_frame(graph, 9, obstacle=False)  # the probe's publishers made; the other process discovers them
        assert graph.wait_for(lambda: graph.probe.count_subscribers(topics.ODOMETRY) >= 2  # the brake and the control
                              and graph.probe.count_subscribers(topics.NETWORK_ACTION) > 0
                              and graph.probe.count_publishers(topics.VEHICLE_CONTROL) > 0, timeout=30.0), \
            log.read_text()
        assert Parameters(graph, "aeb").get("camera_width_px", "release_s") == [WIDTH, 0.0]
        publish_frame(graph, 10, obstacle=True)
        assert graph.wait_for(lambda: any(c.header.stamp.sec == 10 for c in controls)), log.read_text()
        braked = next(c for c in controls if c.header.stamp.sec == 10)
        # the PID's answer to the brake's target speed 0 (the watchdog's brake would not keep the network's steer)
        assert (braked.throttle, braked.brake > 0.5, braked.steer) == (0.0, True, pytest.approx(0.1))
        publish_frame(graph, 11, obstacle=False)
        assert graph.wait_for(lambda: any(c.header.stamp.sec == 11 for c in controls)), log.read_text()
        assert next(c for c in controls if c.header.stamp.sec == 11).throttle > 0.0  # 5 m/s asked, 2 m/s driven
    finally:
        process.send_signal(signal.SIGINT)
        assert process.wait(timeout=20) == 0, log.read_text()
