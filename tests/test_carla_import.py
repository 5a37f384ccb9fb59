"""msfsu-import-carla: carla-ros-bridge recordings (written here in the bridge's formats) -> the stack's bags, which
msfsu-train and msfsu-eval-bag take unchanged; the label table against CARLA's palettes; each bad input in one line."""

import json
import math
import shlex
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from rosbags.interfaces import Connection, ConnectionExtRosbag2, MessageDefinition, MessageDefinitionFormat

from carla_recording import (CARLA_DOC, EXPECTED_CLASS, PALETTES, SPEED_MPS, STRAIGHT_M, TURN_RADIUS_M,
                             TURN_STEER, UNKNOWN_COLOUR, Recording, Truth, on_turn, recipe_objects, write_objects,
                             write_recording)
from msfsu_common import topics
from msfsu_common.bag_io import (CAMERA, IMPORT_REPORT, MAP, SOURCE_BAG, SOURCE_INFO, SPLIT, BagError,
                                  bag_typestore, msfsu_typestore, open_bag, read_bag_metadata)
from msfsu_common.camera_geometry import FrontCamera
from msfsu_common.image_codec import decode_mono8
from msfsu_common.road_option import RoadOption
from msfsu_common.semantic_classes import SemanticClass
from msfsu_control.path_options import BEND_WINDOW_M
from msfsu_control.route_tracker import RouteTrackerConfig
from msfsu_perception.bag_topics import BagTopics
from msfsu_sim.carla.frames import nearest
from msfsu_sim.carla.importer import main
from msfsu_sim.carla.labels import CARLA_TAGS, CITYSCAPES_TAGS, LEGACY_TAGS, UNKNOWN, palette_labels, tag_labels
from msfsu_sim.carla.sensors import front_camera

STACK = BagTopics()
CONTROL = "/carla/ego_vehicle/vehicle_control_cmd"
# a turn is announced the tracker's look-ahead before the bend, at most half the length over which a bend is measured
# earlier
ANNOUNCED_M = RouteTrackerConfig().lookahead_m + BEND_WINDOW_M / 2


# --- the label table -----------------------------------------------------------------------------------------------
@pytest.mark.parametrize("numbering", [LEGACY_TAGS, CITYSCAPES_TAGS])
def test_the_label_table_is_carlas_palette_colour_by_colour(numbering):
    palette = PALETTES[numbering]
    numbered = {tag.name: (tag.legacy if numbering == LEGACY_TAGS else tag.cityscapes) for tag in CARLA_TAGS}
    assert {name: value for name, value in numbered.items() if value is not None} == {
        name: (tag_id, colour) for tag_id, (name, colour) in enumerate(palette)}
    for tag_id, (name, colour) in enumerate(palette):
        expected = EXPECTED_CLASS.get(name, SemanticClass.OTHER)
        assert palette_labels(np.array([[colour]], np.uint8)).class_ids[0, 0] == expected, name
        assert tag_labels(np.array([[tag_id]], np.uint8), numbering).class_ids[0, 0] == expected, name
    beyond = tag_labels(np.array([[len(palette), 255]], np.uint8), numbering)
    assert list(beyond.class_ids[0]) == [UNKNOWN, UNKNOWN] and beyond.unknown == {len(palette): 1, 255: 1}


def test_a_colour_that_is_no_carla_tag_is_counted_never_mapped():
    # the last: 'other' of the palette before 0.9.10, which no tag of 0.9.10 - 0.9.15 has
    image = np.array([[(128, 64, 128), UNKNOWN_COLOUR, UNKNOWN_COLOUR, (250, 170, 160)]], np.uint8)
    labels = palette_labels(image)
    assert list(labels.class_ids[0]) == [SemanticClass.ROAD, UNKNOWN, UNKNOWN, UNKNOWN]
    assert labels.unknown == {UNKNOWN_COLOUR: 2, (250, 170, 160): 1}


# --- the recording's own types ----------------------------------------------------------------------------------
def connection(msgtype: str, definition: str, form: MessageDefinitionFormat = MessageDefinitionFormat.MSG):
    return Connection(1, "/carla/ego_vehicle/vehicle_status", msgtype, MessageDefinition(form, definition), "", 0,
                      ConnectionExtRosbag2("cdr", []), None)


STATUS = "carla_msgs/msg/CarlaEgoVehicleStatus"
SEPARATOR = "=" * 80
STATUS_DEFINITION = (f"std_msgs/Header header\nfloat32 velocity\nCarlaEgoVehicleControl control\n{SEPARATOR}\n"
                     f"MSG: carla_msgs/CarlaEgoVehicleControl\nstd_msgs/Header header\nfloat32 steer\n{SEPARATOR}\n"
                     "MSG: std_msgs/Header\n# the stack's own definition is kept\nbuiltin_interfaces/Time stamp\n"
                     "string frame_id\n")


def test_a_type_only_the_bag_defines_is_read_from_its_definition_and_the_shared_store_stays_as_it_was():
    store = bag_typestore([connection(STATUS, STATUS_DEFINITION)])
    types = store.types

    def header(sec: int):
        return types["std_msgs/msg/Header"](stamp=types["builtin_interfaces/msg/Time"](sec=sec, nanosec=0), frame_id="")

    status = types[STATUS](header=header(3), velocity=2.5,
                           control=types["carla_msgs/msg/CarlaEgoVehicleControl"](header=header(0), steer=-0.25))
    decoded = store.deserialize_cdr(store.serialize_cdr(status, STATUS), STATUS)
    assert (decoded.velocity, decoded.control.steer, decoded.header.stamp.sec) == (2.5, -0.25, 3)
    assert STATUS not in msfsu_typestore().fielddefs


@pytest.mark.parametrize("definition, form, reason", [
    ("", MessageDefinitionFormat.NONE, "is not installed and the bag does not define it"),
    ("float32 velocity\n", MessageDefinitionFormat.IDL, "defines it in IDL, which is not read here"),
    ("float32[ velocity\n", MessageDefinitionFormat.MSG, "the bag's own definition of it is unusable"),
])
def test_a_type_the_bag_does_not_define_usably_is_one_line(definition, form, reason):
    with pytest.raises(BagError, match=reason) as raised:
        bag_typestore([connection(STATUS, definition, form)])
    assert str(raised.value).startswith(f"/carla/ego_vehicle/vehicle_status: type {STATUS}")
    assert "\n" not in str(raised.value)


# --- matching and route commands ---------------------------------------------------------------------------------
def test_nearest_takes_the_closest_time_within_the_tolerance_only():
    times = np.array([300, 100, 200], np.int64)
    assert list(nearest(times, np.array([90, 149, 151, 260, 400, 0]), 50)) == [1, 1, 2, 0, -1, -1]
    assert list(nearest(np.array([], np.int64), np.array([1]), 50)) == [-1]


# --- a recording imported, trained on and evaluated --------------------------------------------------------------
def import_recording(tmp: Path, recording: Recording = Recording(), *options: str,
                     capsys=None) -> tuple[int, Truth, Path, str, str]:
    source, out = tmp / "recording", tmp / "imported"
    tmp.mkdir(parents=True, exist_ok=True)
    truth = write_recording(source, recording)
    objects = [] if "--objects" in options else ["--objects", str(write_objects(tmp / "objects.json", recording))]
    code = main([str(source), "--out", str(out), *objects, *options])
    captured = capsys.readouterr() if capsys else None
    return code, truth, out, captured.out if captured else "", captured.err if captured else ""


def read_output(bag: Path) -> dict[str, list]:
    store = msfsu_typestore()
    messages: dict[str, list] = {}
    with open_bag(bag) as reader:
        for connection, log_ns, raw in reader.messages():
            messages.setdefault(connection.topic, []).append((log_ns, store.deserialize_cdr(raw, connection.msgtype)))
    return messages


def stamp(msg) -> int:
    return msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec


@pytest.fixture(scope="module")
def imported(tmp_path_factory):
    """The default recording imported twice, as training and as validation data (the docs' commands)."""
    root = tmp_path_factory.mktemp("carla")
    truth = write_recording(root / "recording")
    write_objects(root / "msfsu_objects.json", Recording(), x=1.5, z=1.8, pitch=-5.0)  # where the recipe saves it
    outputs = {}
    for split in ("train", "validation"):
        outputs[split] = root / "bags" / split
        result = subprocess.run([str(Path(sys.executable).parent / "msfsu-import-carla"), str(root / "recording"),
                                 "--out", str(outputs[split]), "--split", split], capture_output=True, text=True,
                                cwd=root)
        assert result.returncode == 0, result.stderr
    return root, truth, outputs, result.stdout


def test_each_camera_frame_becomes_a_sample_with_its_labels_action_and_command(imported):
    root, truth, outputs, printed = imported
    messages = read_output(outputs["train"])
    frames = len(truth.stamps_ns)
    assert {topic: len(items) for topic, items in messages.items()} == {
        STACK.rgb: frames, STACK.depth: frames, STACK.semantic_ids: frames, STACK.expert_action: frames,
        STACK.navigation_command: frames, topics.ODOMETRY: frames}
    for topic in (STACK.rgb, STACK.depth, STACK.semantic_ids, STACK.expert_action, STACK.navigation_command):
        assert [stamp(msg) for _, msg in messages[topic]] == truth.stamps_ns  # the frame's stamp everywhere
    for (_, ids), expected in zip(messages[STACK.semantic_ids], truth.class_ids):
        assert ids.encoding == "mono8" and np.array_equal(decode_mono8(ids), expected)
    actions = [msg for _, msg in messages[STACK.expert_action]]
    assert [a.steer for a in actions] == pytest.approx(truth.steer)
    assert min(a.steer for a in actions) == pytest.approx(TURN_STEER)  # CARLA's steer as it is: negative is left
    assert [a.target_speed for a in actions] == pytest.approx([SPEED_MPS] * frames)
    commands = np.array([msg.command for _, msg in messages[STACK.navigation_command]])
    arcs = np.array(truth.arc_m)
    assert (commands[[on_turn(arc) for arc in arcs]] == RoadOption.LEFT).all()
    turn_end = STRAIGHT_M + TURN_RADIUS_M * math.pi / 2
    assert (commands[(arcs < STRAIGHT_M - ANNOUNCED_M - 2) | (arcs > turn_end + 7)] == RoadOption.LANE_FOLLOW).all()
    assert set(commands) == {RoadOption.LEFT, RoadOption.LANE_FOLLOW}
    assert [a.command for a in actions] == list(commands)
    # log times on the frames' clock: the command before the frame's images, which a player sends first
    assert [log for log, _ in messages[STACK.rgb]] == truth.stamps_ns
    assert all(log < frame for (log, _), frame in zip(messages[STACK.navigation_command], truth.stamps_ns))
    assert "carla_msgs/msg/CarlaEgoVehicleControl" not in msfsu_typestore().fielddefs  # read from the bag only
    assert "placed by log time" in printed and "derived from the route" in printed


def test_the_output_records_where_it_came_from(imported):
    root, truth, outputs, _ = imported
    metadata = read_bag_metadata(outputs["validation"])
    assert metadata[SPLIT] == "validation" and metadata[MAP] == "Town01"
    assert metadata[SOURCE_BAG] == str((root / "recording").resolve())
    source = json.loads(metadata[SOURCE_INFO])
    assert source["topics"][CONTROL] == {"type": "carla_msgs/msg/CarlaEgoVehicleControl", "messages": len(truth.steer)}
    assert source["recovered"] == [] and source["duration"]["nanoseconds"] > 0
    report = json.loads(metadata[IMPORT_REPORT])
    assert report["frames"] == report["camera_frames"] == len(truth.steer)
    assert report["sources"]["steer"].startswith(f"{CONTROL} steer")
    assert report["settings"]["tolerance_s"] == 0.05 and report["settings"]["route"]["lookahead_m"] == 15.0
    # the camera of the sensor definition the recording was spawned with (CARLA: x ahead, y right, z up, pitch up)
    assert FrontCamera.from_json(metadata[CAMERA]) == FrontCamera(width=80, height=60, fov_deg=90.0, forward_m=1.5,
                                                                   right_m=0.0, up_m=1.8, pitch_deg=-5.0)


def test_the_recipes_sensor_definition_is_one_pose_for_its_three_cameras(tmp_path):
    """docs/carla.md's file: RGB, depth and semantic at one pose with one lens (the stack pairs their pixels), 800x600
    as in the paper; the camera the import takes from it is that pose."""
    objects = recipe_objects()
    cameras = [sensor for sensor in objects["objects"][0]["sensors"] if sensor["type"].startswith("sensor.camera")]
    assert len(cameras) == 3
    assert all({k: v for k, v in c.items() if k not in ("type", "id")} ==
               {k: v for k, v in cameras[0].items() if k not in ("type", "id")} for c in cameras)
    path = tmp_path / "msfsu_objects.json"
    path.write_text(json.dumps(objects))
    assert front_camera(path, "ego_vehicle", "rgb_front") == FrontCamera(
        width=800, height=600, fov_deg=90.0, forward_m=2.0, right_m=0.0, up_m=2.0, pitch_deg=0.0)


def test_a_sensor_definition_that_does_not_fit_the_recording_is_one_line(tmp_path, capsys):
    """The camera goes into the output's metadata, so the import checks it: a file that is there, the recorded size,
    a depth camera at the RGB camera's pose, a camera that looks ahead."""
    def refused(objects: Path | dict) -> str:
        run = tmp_path / f"run{len(list(tmp_path.glob('run*')))}"
        run.mkdir()
        if isinstance(objects, dict):
            path = run / "objects.json"
            path.write_text(json.dumps(objects))
            objects = path
        code, _, out, _, err = import_recording(run, Recording(frames=2), "--objects", str(objects), capsys=capsys)
        assert code == 1 and not out.exists()
        return one_line(err)

    missing = tmp_path / "none.json"
    assert refused(missing).startswith(f"msfsu-import-carla: cannot read the sensor definition {missing} (No such "
                                       "file or directory): give the carla_spawn_objects file")
    assert refused(recipe_objects()) == (
        f"msfsu-import-carla: /carla/ego_vehicle/rgb_front/image is 80x60, camera 'rgb_front' of "
        f"{tmp_path / 'run1' / 'objects.json'} 800x600: give the sensor definition the recording was spawned with "
        "(--objects FILE)")
    objects = recipe_objects()
    for sensor in objects["objects"][0]["sensors"]:
        if sensor["type"].startswith("sensor.camera"):
            sensor.update(image_size_x=80, image_size_y=60)
    objects["objects"][0]["sensors"][1]["spawn_point"]["z"] = 2.5  # the depth camera higher than the RGB one
    assert refused(objects).startswith(f"msfsu-import-carla: {tmp_path / 'run2' / 'objects.json'}: the depth camera "
                                       "'depth_front' is not at the RGB camera's pose with its lens")
    objects["objects"][0]["sensors"][1]["spawn_point"].update(z=2.0, yaw=180.0)  # a depth camera looking back
    assert refused(objects).startswith(f"msfsu-import-carla: {tmp_path / 'run3' / 'objects.json'}: camera "
                                       "'depth_front' of 'ego_vehicle' is not a front camera: yaw 180.0")
    objects["objects"][0]["sensors"][1]["spawn_point"]["yaw"] = 0.0
    objects["objects"][0]["sensors"][0]["spawn_point"]["yaw"] = 180.0  # a rear camera
    assert refused(objects).startswith(f"msfsu-import-carla: {tmp_path / 'run4' / 'objects.json'}: camera "
                                       "'rgb_front' of 'ego_vehicle' is not a front camera: yaw 180.0")


# what the docs' commands leave to their defaults that a test on two cores gives: a short run, one cache
SMOKE_OPTIONS = {"msfsu-train": ["--epochs", "1", "--max-steps", "2", "--batch-size", "2", "--num-threads", "1",
                                 "--cache-dir", "cache"],
                 "msfsu-eval-bag": ["--rate", "0.5", "--cache-dir", "cache"]}


def docs_commands(heading: str) -> list[list[str]]:
    """The commands of the first bash block after `heading` in docs/carla.md, one per line."""
    text = CARLA_DOC.read_text()
    block = text[text.index(heading):].split("```bash\n", 1)[1].split("```", 1)[0]
    return [shlex.split(line) for line in block.splitlines() if line.strip() and not line.startswith("#")]


def test_the_docs_commands_take_one_recording_to_a_checkpoint_and_its_evaluation(tmp_path):
    """docs/carla.md's commands as written, on one recording named as there: one bag in, a checkpoint out, scored."""
    commands = docs_commands("## Import, train, evaluate")
    assert [command[0] for command in commands] == ["msfsu-import-carla", "msfsu-train", "msfsu-eval-bag"]
    truth = write_recording(tmp_path / commands[0][1])
    write_objects(tmp_path / "msfsu_objects.json", Recording())  # saved as the recipe says, beside the recording
    for program, *arguments in commands:
        result = subprocess.run([str(Path(sys.executable).parent / program), *arguments,
                                 *SMOKE_OPTIONS.get(program, [])], cwd=tmp_path, capture_output=True, text=True,
                                timeout=600)
        assert result.returncode == 0, (program, result.stdout[-2000:], result.stderr[-3000:])
    out = tmp_path / commands[2][commands[2].index("--out") + 1]
    report = json.loads((out / "report.json").read_text())
    frames = report["frames"]
    assert frames["camera_frames"] == frames["with_ground_truth"] == len(truth.steer)
    assert frames["processed"] >= len(truth.steer) // 2 and report["segmentation"]["labelled_pixels"] > 0
    assert set(report["actions"]) >= {"overall", "LEFT", "LANE_FOLLOW"}
    # the brake saw with the recording's camera, which the import took from the sensor definition
    assert report["run"]["aeb_camera"] == {"width": 80, "height": 60, "fov_deg": 90.0, "forward_m": 2.0,
                                           "right_m": 0.0, "up_m": 2.0, "pitch_deg": 0.0}


def test_msfsu_train_on_an_import_without_labels_says_in_one_line_what_trains_on_it(tmp_path, capsys):
    from msfsu_perception.train import main as train

    code, _, out, _, _ = import_recording(tmp_path, Recording(frames=20, semantic=None), "--no-labels", capsys=capsys)
    assert code == 0
    with pytest.raises(SystemExit) as stopped:
        train(["--train-bags", str(out), "--val-fraction", "0.2", "--out", str(tmp_path / "run"), "--cache-dir",
               str(tmp_path / "cache"), "--preset", "cpu", "--num-threads", "1"])
    message = str(stopped.value)
    assert message.startswith(f"msfsu-train: bag {out.resolve()} lacks topics ['{STACK.semantic_ids}'] (topics: ")
    assert "\n" not in message and message.endswith("train --variant msf, which needs none, or record (import) the "
                                                    "bag with its semantic camera")


def test_a_raw_bridge_recording_given_to_msfsu_eval_bag_points_at_the_import(tmp_path, tiny_checkpoint, capsys):
    from msfsu_evaluation.bag_eval import main as eval_bag

    source = tmp_path / "recording"
    write_recording(source, Recording(frames=4))
    code = eval_bag([str(source), "--checkpoint", str(tiny_checkpoint), "--out", str(tmp_path / "eval"),
                     "--cache-dir", str(tmp_path / "cache")])
    line = one_line(capsys.readouterr().err)
    assert code == 1 and not (tmp_path / "eval" / "recording").exists()
    assert line.startswith(f"msfsu-eval-bag: bag {source} is a carla-ros-bridge recording (carla_msgs on "
                           "/carla/ego_vehicle/vehicle_control_cmd, /carla/ego_vehicle/vehicle_status, "
                           "/carla/world_info), without the stack's ground truth (expert action /msfsu/expert/")
    assert line.endswith(f"import it first, `msfsu-import-carla {source} --out DIR --split test`, then evaluate DIR "
                         "(docs/carla.md)")


# --- what a recording may hold instead -----------------------------------------------------------------------------
def test_raw_tag_images_are_read_in_the_numbering_given(tmp_path, capsys):
    code, truth, out, printed, _ = import_recording(tmp_path, Recording(frames=6, semantic=LEGACY_TAGS),
                                                    "--raw-tags", LEGACY_TAGS, capsys=capsys)
    assert code == 0 and "raw tags, CARLA 0.9.10-0.9.13" in printed
    ids = [decode_mono8(msg) for _, msg in read_output(out)[STACK.semantic_ids]]
    assert all(np.array_equal(got, expected) for got, expected in zip(ids, truth.class_ids)) and len(ids) == 6


def test_the_palette_of_carla_0910_to_0913_reads_the_same_classes(tmp_path, capsys):
    code, truth, out, _, _ = import_recording(tmp_path, Recording(frames=4, palette=LEGACY_TAGS), capsys=capsys)
    ids = [decode_mono8(msg) for _, msg in read_output(out)[STACK.semantic_ids]]
    assert code == 0 and all(np.array_equal(got, expected) for got, expected in zip(ids, truth.class_ids))


def test_an_autopilot_drive_takes_the_applied_control_and_a_recorded_command(tmp_path, capsys):
    recording = Recording(frames=30, with_control=False, with_route=False,
                          command_topic="/carla/ego_vehicle/road_option")
    code, truth, out, printed, _ = import_recording(
        tmp_path, recording, "--control-topic", "/carla/ego_vehicle/vehicle_status",
        "--command-topic", "/carla/ego_vehicle/road_option", capsys=capsys)
    assert code == 0 and "recorded: /carla/ego_vehicle/road_option" in printed
    messages = read_output(out)
    assert [msg.steer for _, msg in messages[STACK.expert_action]] == pytest.approx(truth.steer)
    commands = [msg.command for _, msg in messages[STACK.navigation_command]]
    assert commands == [RoadOption.LEFT if on_turn(arc) else RoadOption.LANE_FOLLOW for arc in truth.arc_m]


def test_without_a_status_topic_the_speed_is_the_odometrys(tmp_path, capsys):
    code, truth, out, printed, _ = import_recording(tmp_path, Recording(frames=4, with_status=False), capsys=capsys)
    assert code == 0 and "/carla/ego_vehicle/odometry |twist.linear|" in printed
    assert [msg.target_speed for _, msg in read_output(out)[STACK.expert_action]] == pytest.approx([SPEED_MPS] * 4)


# --- bad input: one line, never a traceback ----------------------------------------------------------------------
def one_line(err: str) -> str:
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in err, err
    return lines[0]


def test_without_a_semantic_camera_the_import_is_refused_unless_no_labels_are_asked_for(tmp_path, capsys):
    code, _, out, printed, err = import_recording(tmp_path / "asked", Recording(frames=4, semantic=None),
                                                  capsys=capsys)
    assert code == 1 and not out.exists() and not printed
    line = one_line(err)
    assert line.startswith("msfsu-import-carla: no semantic camera on "
                           "/carla/ego_vehicle/semantic_segmentation_front/image (topics: /carla/ego_vehicle/"
                           "depth_front/image, /carla/ego_vehicle/odometry, /carla/ego_vehicle/rgb_front/image, ")
    assert line.endswith("/carla/world_info, /clock): the labels msfsu-train needs for the msfsu and su variants; name "
                         "it with --semantic-topic, or import without labels with --no-labels (for msfsu-eval-bag and "
                         "msfsu-train --variant msf)")
    code, _, out, printed, err = import_recording(tmp_path / "none", Recording(frames=4, semantic=None),
                                                  "--no-labels", capsys=capsys)
    assert code == 0 and not err
    assert "labels: none: --no-labels" in printed and "imported for evaluation only" in printed
    assert STACK.semantic_ids not in read_output(out) and len(read_output(out)[STACK.rgb]) == 4


def test_no_labels_leaves_a_recorded_semantic_camera_out(tmp_path, capsys):
    code, _, out, printed, err = import_recording(tmp_path, Recording(frames=4), "--no-labels", capsys=capsys)
    assert code == 0 and not err and "labels: none: --no-labels" in printed
    assert STACK.semantic_ids not in read_output(out) and len(read_output(out)[STACK.rgb]) == 4


def test_an_output_that_exists_is_refused_and_force_replaces_it_only_if_it_is_a_bag(tmp_path, capsys):
    code, _, out, _, _ = import_recording(tmp_path, Recording(frames=4), "--no-labels", capsys=capsys)
    assert code == 0 and STACK.semantic_ids not in read_output(out)
    objects = str(tmp_path / "objects.json")
    again = [str(tmp_path / "recording"), "--out", str(out), "--objects", objects]
    assert main(again) == 1
    assert one_line(capsys.readouterr().err) == (f"msfsu-import-carla: {out} exists; the import writes a new bag "
                                                 "directory (--force replaces it)")
    assert main([*again, "--force"]) == 0  # now with labels: the new bag, whole, where the old one was
    capsys.readouterr()
    assert len(read_output(out)[STACK.semantic_ids]) == 4 and not list(tmp_path.glob(".*partial*"))
    notes = tmp_path / "notes"
    (notes / "keep.txt").parent.mkdir()
    (notes / "keep.txt").write_text("not a bag")
    assert main([str(tmp_path / "recording"), "--out", str(notes), "--objects", objects, "--force"]) == 1
    assert one_line(capsys.readouterr().err) == (f"msfsu-import-carla: {notes} exists and is no bag directory: --force "
                                                 "replaces only a bag")
    assert (notes / "keep.txt").read_text() == "not a bag"


def test_the_sensor_definition_is_read_in_either_layout_of_the_bridges_files(tmp_path):
    """carla_spawn_objects' file with the vehicle's sensors under `sensors` or nested under its `objects`, and
    carla_ego_vehicle's `{"sensors": [...]}` whose poses sit beside the other attributes: one camera."""
    expected = front_camera(write_objects(tmp_path / "recipe.json", Recording()), "ego_vehicle", "rgb_front")
    vehicle = recipe_objects()["objects"][0]
    for sensor in vehicle["sensors"]:
        sensor.update(image_size_x=80, image_size_y=60)
    nested = {"objects": [{"type": "sensor.pseudo.traffic_lights", "id": "traffic_lights"},
                          {**{k: v for k, v in vehicle.items() if k != "sensors"}, "objects": vehicle["sensors"]}]}
    flat = {"sensors": [{**{k: v for k, v in sensor.items() if k != "spawn_point"}, **sensor.get("spawn_point", {})}
                        for sensor in vehicle["sensors"]]}
    for name, definition in (("nested", nested), ("flat", flat)):
        path = tmp_path / f"{name}.json"
        path.write_text(json.dumps(definition))
        assert front_camera(path, "ego_vehicle", "rgb_front") == expected, name
    (tmp_path / "neither.json").write_text(json.dumps({"actors": []}))
    with pytest.raises(ValueError, match="is no carla_spawn_objects definition .*: it lists neither 'objects' nor "
                                         "'sensors'$"):
        front_camera(tmp_path / "neither.json", "ego_vehicle", "rgb_front")


@pytest.mark.parametrize("option", ["--semantic-topic", "--depth-topic", "--status-topic"])
def test_a_mistyped_topic_is_refused_listing_the_recordings_topics(tmp_path, capsys, option):
    code, _, out, printed, err = import_recording(tmp_path, Recording(frames=4), option, "/carla/ego_vehicle/typo",
                                                  capsys=capsys)
    line = one_line(err)
    assert code == 1 and not out.exists() and not printed
    assert line.startswith(f"msfsu-import-carla: {tmp_path / 'recording'}: no {option} /carla/ego_vehicle/typo "
                           "(topics: /carla/ego_vehicle/depth_front/image, ")
    assert "/carla/ego_vehicle/semantic_segmentation_front/image" in line
    assert line.endswith("/carla/world_info, /clock)")


def test_raw_tags_asked_of_a_palette_image_are_refused_suggesting_to_drop_the_flag(tmp_path, capsys):
    code, _, out, _, err = import_recording(tmp_path, Recording(frames=4), "--raw-tags", CITYSCAPES_TAGS,
                                            capsys=capsys)
    assert code == 1 and not out.exists()
    line = one_line(err)
    assert line.startswith(f"msfsu-import-carla: --raw-tags {CITYSCAPES_TAGS}: "
                           "/carla/ego_vehicle/semantic_segmentation_front/image holds CityScapes palette colours "
                           "(e.g. (")
    assert line.endswith("not raw tags in the red channel: import it without --raw-tags")


def test_a_raw_tag_image_read_as_palette_colours_suggests_raw_tags(tmp_path, capsys):
    code, _, out, _, err = import_recording(tmp_path, Recording(frames=2, semantic=LEGACY_TAGS), capsys=capsys)
    assert code == 1 and not out.exists()
    assert one_line(err).endswith(f"they look like raw tags in the red channel: --raw-tags {LEGACY_TAGS} or "
                                  f"--raw-tags {CITYSCAPES_TAGS}")


def test_without_control_the_import_is_refused_naming_the_topic(tmp_path, capsys):
    code, _, out, _, err = import_recording(tmp_path, Recording(frames=4, with_control=False), capsys=capsys)
    line = one_line(err)
    assert code == 1 and not out.exists()
    assert f"no {CONTROL} (CarlaEgoVehicleControl): no expert action" in line
    assert "--control-topic /carla/ego_vehicle/vehicle_status" in line


def test_depth_in_millimetres_is_kept_and_a_depth_that_is_no_distance_refused(tmp_path, capsys):
    code, _, out, _, err = import_recording(tmp_path / "mm", Recording(frames=4, depth_encoding="16UC1"), capsys=capsys)
    assert code == 0 and not err
    assert {msg.encoding for _, msg in read_output(out)[STACK.depth]} == {"16UC1"}
    code, _, out, _, err = import_recording(tmp_path / "raw", Recording(frames=4, depth_encoding="bgra8"),
                                            capsys=capsys)
    assert code == 1 and not out.exists()
    assert one_line(err) == ("msfsu-import-carla: /carla/ego_vehicle/depth_front/image is bgra8: the import reads "
                             "depth as 32FC1 metres (as carla-ros-bridge publishes it) or 16UC1 millimetres")


def test_cameras_of_different_sizes_are_refused(tmp_path, capsys):
    code, _, out, _, err = import_recording(tmp_path, Recording(frames=2, depth_rows=30), capsys=capsys)
    assert code == 1 and not out.exists()
    assert one_line(err) == ("msfsu-import-carla: /carla/ego_vehicle/depth_front/image is 80x30, the RGB camera "
                             "80x60: the stack pairs their pixels; give the cameras one size")


def test_frames_whose_stamp_goes_back_are_dropped_and_counted(tmp_path, capsys):
    code, truth, out, printed, err = import_recording(tmp_path, Recording(frames=10, stamp_back_at=5), capsys=capsys)
    assert code == 0 and not err
    assert "8 of 10 camera frames (dropped: 2 stamp_not_increasing)" in printed
    stamps = [stamp(msg) for _, msg in read_output(out)[STACK.rgb]]
    assert stamps == sorted(set(stamps)) and len(stamps) == 8


def test_frames_with_colours_that_are_no_tag_are_dropped_and_reported(tmp_path, capsys):
    code, _, out, printed, _ = import_recording(tmp_path / "some", Recording(frames=6, unknown_colour_frames=(1, 4)),
                                                capsys=capsys)
    assert code == 0 and "4 of 6 camera frames (dropped: 2 unknown_label)" in printed
    assert f"2 frames hold colours that are no CARLA tag, most frequent (pixels): {UNKNOWN_COLOUR} 2" in printed
    code, _, out, _, err = import_recording(tmp_path / "all", Recording(frames=2, unknown_colour_frames=(0, 1)),
                                            capsys=capsys)
    assert code == 1 and not out.exists() and "every frame's semantic image holds colours" in one_line(err)


def test_a_truncated_recording_is_imported_from_what_it_holds(tmp_path, capsys):
    source = tmp_path / "recording"
    recording = Recording(frames=40, width=160, height=120)
    truth = write_recording(source, recording)
    (source / "metadata.yaml").unlink()  # a recorder killed: no metadata.yaml, the file cut short
    mcap = next(source.glob("*.mcap"))
    mcap.write_bytes(mcap.read_bytes()[: mcap.stat().st_size * 2 // 3])
    code = main([str(source), "--out", str(tmp_path / "imported"), "--objects",
                 str(write_objects(tmp_path / "objects.json", recording))])
    printed, err = capsys.readouterr()
    assert code == 0
    assert one_line(err).startswith(f"msfsu-import-carla: damaged bag, recovered what it holds: {mcap}: no footer")
    kept = len(read_output(tmp_path / "imported")[STACK.rgb])
    assert 0 < kept < len(truth.steer) and f"{kept} of " in printed


def test_a_recording_without_the_bags_own_definitions_is_refused(tmp_path, capsys):
    code, _, out, _, err = import_recording(tmp_path, Recording(frames=2, definitions=False), capsys=capsys)
    assert code == 1 and not out.exists()
    assert one_line(err) == (f"msfsu-import-carla: {CONTROL}: type carla_msgs/msg/CarlaEgoVehicleControl is not "
                             "installed and the bag does not define it (record with ros2 bag record -s mcap)")


def test_frames_driven_in_reverse_are_dropped(tmp_path, capsys):
    code, _, _, printed, _ = import_recording(tmp_path, Recording(frames=6, reverse_frames=(2,)), capsys=capsys)
    assert code == 0 and "5 of 6 camera frames (dropped: 1 reverse)" in printed
