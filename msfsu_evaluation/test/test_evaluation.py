"""Matching graph outputs to ground truth by stamp, without ROS: hand-made outputs with known scores."""

from pathlib import Path

import numpy as np
import pytest

from msfsu_common import topics
from msfsu_common.bag_io import mcap_writer, msfsu_typestore
from msfsu_common.image_codec import encode_image
from msfsu_common.road_option import RoadOption
from msfsu_evaluation.evaluation import evaluate
from msfsu_evaluation.ground_truth import GroundTruth, load_ground_truth
from msfsu_evaluation.recording import RecordedOutputs
from msfsu_perception.bag_topics import BagTopics
from msfsu_perception.preprocessing import PreprocessConfig
from msfsu_perception.synthetic import write_synthetic_bag

N_FRAMES = 6
ANSWERED = [0, 1, 2, 4]  # frames 3 and 5 get no action: skipped
LATENCY_MS = [10.0, 20.0, 30.0, 50.0]
PREPROCESS = PreprocessConfig(input_height=32, input_width=32)


@pytest.fixture
def truth(tmp_path) -> GroundTruth:
    write_synthetic_bag(tmp_path / "bag", n_frames=N_FRAMES)
    return load_ground_truth(tmp_path / "bag", BagTopics(), PREPROCESS, tmp_path / "cache")


def write_segmentation(path: Path, stamps_ns: list[int], class_ids: list[np.ndarray]) -> None:
    store = msfsu_typestore()
    types = store.types
    with mcap_writer(path) as writer:
        connection = writer.add_connection(topics.SEGMENTATION, "sensor_msgs/msg/Image", typestore=store)
        for stamp, ids in zip(stamps_ns, class_ids):
            fields = encode_image(ids, "mono8")
            fields["data"] = np.frombuffer(fields["data"], np.uint8)
            header = types["std_msgs/msg/Header"](
                stamp=types["builtin_interfaces/msg/Time"](sec=stamp // 10**9, nanosec=stamp % 10**9), frame_id="")
            msg = types["sensor_msgs/msg/Image"](header=header, **fields)
            writer.write(connection, stamp, store.serialize_cdr(msg, msg.__msgtype__))


def hand_made_outputs(truth: GroundTruth) -> RecordedOutputs:
    """Steer 0.1 right of the expert, speed 1 m/s below, answers LATENCY_MS after each frame's receipt;
    the first answer comes from another branch than the expert's command."""
    frame_received = {int(stamp): 5_000_000_000 + index * 100_000_000 for index, stamp in enumerate(truth.stamps_ns)}
    stamps = truth.stamps_ns[ANSWERED]
    command = truth.command[ANSWERED].copy()
    command[0] = RoadOption.RIGHT if command[0] != RoadOption.RIGHT else RoadOption.LEFT
    return RecordedOutputs(
        action_stamps_ns=stamps,
        steer=truth.steer[ANSWERED] + np.float32(0.1),
        target_speed=truth.target_speed[ANSWERED] - np.float32(1.0),
        command=command,
        action_received_ns=np.array([frame_received[int(stamp)] + int(ms * 1e6)
                                     for stamp, ms in zip(stamps, LATENCY_MS)]),
        frame_received_ns=frame_received,
        control_stamps_ns={int(stamps[0])},
        perception_diagnostics={"processed": "4"},
    )


def test_outputs_are_matched_by_stamp_and_scored(truth, tmp_path):
    recording = tmp_path / "recording"
    # Perfect segmentation for every answered frame but the last, which predicts "road" everywhere.
    predictions = [truth.class_ids(row) for row in ANSWERED[:-1]] + [np.zeros((32, 32), np.uint8)]
    write_segmentation(recording, [int(truth.stamps_ns[row]) for row in ANSWERED], predictions)
    evaluation = evaluate(truth, hand_made_outputs(truth), recording, num_classes=5, overlay_count=2)

    frames = evaluation.frames
    counts = (frames.camera_frames, frames.processed, frames.skipped, frames.evaluated, frames.controlled)
    assert counts == (6, 4, 2, 4, 1)
    assert frames.command_mismatches == 1
    overall = evaluation.actions["overall"]
    assert overall.frames == 4
    assert overall.steer_mae == pytest.approx(0.1, abs=1e-6) and overall.steer_rmse == pytest.approx(0.1, abs=1e-6)
    assert overall.target_speed_mae == pytest.approx(1.0, abs=1e-6)
    assert sum(errors.frames for name, errors in evaluation.actions.items() if name != "overall") == 4
    assert set(evaluation.actions) - {"overall"} <= {option.name for option in RoadOption}
    latency = evaluation.latency
    assert (latency.frames, latency.p50_ms, latency.max_ms) == (4, pytest.approx(25.0), pytest.approx(50.0))
    np.testing.assert_allclose(evaluation.series.latency_ms, LATENCY_MS, atol=1e-6)

    last = truth.class_ids(ANSWERED[-1])
    wrong_pixels = int(np.count_nonzero(last != 0))
    assert evaluation.segmentation.labelled_pixels == 4 * 32 * 32
    assert evaluation.segmentation.pixel_accuracy == pytest.approx(1.0 - wrong_pixels / (4 * 32 * 32))
    # correct non-road pixels: all of them in the perfect frames, none in the all-road one
    assert evaluation.confusion[1:, 1:].trace() == sum(np.count_nonzero(truth.class_ids(row)) for row in ANSWERED[:-1])
    assert [overlay.stamp_ns for overlay in evaluation.overlays] == [int(truth.stamps_ns[row]) for row in (0, 4)]


def test_a_segmentation_whose_action_was_not_recorded_is_left_out_of_the_scores(truth, tmp_path):
    """The replay's last frame, or a starved recorder: a segmentation arrived but its DrivingAction did not; every
    metric of the report has one sample, the evaluated frames (seen in CI: 30 frames segmented, 29 evaluated)."""
    recording = tmp_path / "recording"
    segmented = [*ANSWERED, 3]  # frame 3 has no action
    write_segmentation(recording, [int(truth.stamps_ns[row]) for row in segmented],
                       [truth.class_ids(row) for row in segmented])
    evaluation = evaluate(truth, hand_made_outputs(truth), recording, num_classes=5, overlay_count=6)
    assert evaluation.frames.evaluated == len(ANSWERED)
    assert evaluation.segmentation.labelled_pixels == len(ANSWERED) * 32 * 32
    assert int(truth.stamps_ns[3]) not in {overlay.stamp_ns for overlay in evaluation.overlays}


def test_no_action_for_any_ground_truth_frame_is_an_error(truth, tmp_path):
    outputs = hand_made_outputs(truth)
    silent = RecordedOutputs(
        action_stamps_ns=np.array([], np.int64), steer=np.array([], np.float32), target_speed=np.array([], np.float32),
        command=np.array([], np.uint8), action_received_ns=np.array([], np.int64),
        frame_received_ns=outputs.frame_received_ns, control_stamps_ns=set(), perception_diagnostics={},
    )
    with pytest.raises(ValueError, match="none of the 6 frames with ground truth got a DrivingAction"):
        evaluate(truth, silent, tmp_path / "recording", num_classes=5)


def test_segmentation_at_another_resolution_than_the_network_input_is_rejected(truth, tmp_path):
    write_segmentation(tmp_path / "recording", [int(truth.stamps_ns[0])], [np.zeros((16, 16), np.uint8)])
    with pytest.raises(ValueError, match="segmentation is 16x16 but the ground truth .* is 32x32"):
        evaluate(truth, hand_made_outputs(truth), tmp_path / "recording", num_classes=5)


def _header(types, stamp: int):
    return types["std_msgs/msg/Header"](
        stamp=types["builtin_interfaces/msg/Time"](sec=stamp // 10**9, nanosec=stamp % 10**9), frame_id="")


def test_with_an_emergency_brake_the_networks_own_actions_are_scored_and_its_interventions_counted(tmp_path):
    """A recording of a graph with the aeb node: /msfsu/network/driving_action is the network's (scored), and
    /msfsu/driving_action what the brake sent on (its receipt is the frame's answer); the brake braked two frames in
    a row, then let go."""
    from msfsu_evaluation.evaluation import brake_interventions
    from msfsu_evaluation.recording import read_outputs

    store = msfsu_typestore()
    types = store.types
    stamps = [1_000_000_000 + index * 100_000_000 for index in range(4)]
    decisions = {stamps[1]: "brake", stamps[2]: "brake", stamps[3]: "none"}  # the last: let go
    with mcap_writer(tmp_path / "recording") as writer:
        network = writer.add_connection(topics.NETWORK_ACTION, "msfsu_interfaces/msg/DrivingAction", typestore=store)
        sent = writer.add_connection(topics.DRIVING_ACTION, "msfsu_interfaces/msg/DrivingAction", typestore=store)
        brake = writer.add_connection(topics.AEB_INTERVENTION, "msfsu_interfaces/msg/AebIntervention",
                                      typestore=store)
        for index, stamp in enumerate(stamps):
            action = types["msfsu_interfaces/msg/DrivingAction"](header=_header(types, stamp), steer=0.1 * index,
                                                                 target_speed=5.0, command=4)
            writer.write(network, stamp + 1, store.serialize_cdr(action, action.__msgtype__))
            out = types["msfsu_interfaces/msg/DrivingAction"](
                header=_header(types, stamp), steer=0.1 * index, command=4,
                target_speed=0.0 if decisions.get(stamp) == "brake" else 5.0)
            writer.write(sent, stamp + 2, store.serialize_cdr(out, out.__msgtype__))
            if stamp in decisions:
                report = types["msfsu_interfaces/msg/AebIntervention"](
                    header=_header(types, stamp), decision=decisions[stamp], reason="", gap_m=1.5, ttc_s=0.8,
                    obstacle_pixels=20, target_speed_in=5.0, target_speed_out=0.0, dropped="")
                writer.write(brake, stamp + 3, store.serialize_cdr(report, report.__msgtype__))
    outputs = read_outputs(tmp_path / "recording")
    assert list(outputs.target_speed) == [5.0] * 4  # the network's own, not the braked ones
    assert list(outputs.action_received_ns) == [stamp + 2 for stamp in stamps]  # answered when the brake sent it on
    counted = brake_interventions(outputs)
    assert (counted.frames, counted.capped, counted.braked, counted.interventions) == (4, 0, 2, 1)
