"""Per-step telemetry (closed_loop.telemetry), the camera geometry it uses and the collision page made from it."""

import math

import numpy as np
import pytest

from msfsu_evaluation.closed_loop import telemetry
from msfsu_evaluation.closed_loop.collisions import collision_windows, collisions_markdown, where_before
from msfsu_evaluation.closed_loop.episode_record import EpisodeResult
from msfsu_evaluation.closed_loop.runner import telemetry_path
from msfsu_evaluation.closed_loop.runs import Record
from msfsu_evaluation.closed_loop.telemetry import (COLUMNS, DriverStep, ExpertLabel, TelemetryRecorder, load,
                                                    nearest_ahead)
from msfsu_common.camera_geometry import CameraView, appearance, visible_fraction
from msfsu_sim.scene import PEDESTRIAN, VEHICLE, Obstacle

# the simulator's front camera (400x300, 2.1 m above the ground, 1 m ahead of the centre) and a 128x128 crop
VIEW = CameraView(400, 300, 1.0, 0.0, 2.095, -2.0, 80.0, 0.5, 128, 128)


def test_a_point_ahead_on_the_ground_projects_to_the_centre_column_and_the_row_of_its_depression():
    column, row, depth = VIEW.project(np.array([21.0]), np.array([0.0]), np.array([0.0]))
    assert column[0] == pytest.approx(200.0)
    pitch = math.radians(-2.0)  # the optical axis, (cos, sin) in (ahead, up), dotted with the point's offset
    assert depth[0] == pytest.approx(20.0 * math.cos(pitch) - 2.095 * math.sin(pitch), rel=1e-6)
    below = math.degrees(math.atan2(2.095, 20.0)) - 2.0  # degrees below the optical axis
    assert row[0] == pytest.approx(150.0 + VIEW.focal_px * math.tan(math.radians(below)), abs=0.5)


def test_a_pedestrian_ahead_is_in_the_crop_and_shrinks_with_distance_one_behind_or_aside_is_not_in_view():
    near = appearance(VIEW, 10.0, 0.0, 0.0, 0.8, 0.8, 1.8)
    far = appearance(VIEW, 30.0, 0.0, 0.0, 0.8, 0.8, 1.8)
    assert near.in_view and near.in_crop and far.in_crop
    assert near.height_px > 2 * far.height_px and near.width_px > 2 * far.width_px
    assert not appearance(VIEW, -5.0, 0.0, 0.0, 0.8, 0.8, 1.8).in_view  # behind the car
    assert not appearance(VIEW, 5.0, 20.0, 0.0, 0.8, 0.8, 1.8).in_view  # 76 degrees to the right: beyond 40
    beyond = appearance(VIEW, 300.0, 0.0, 0.0, 0.8, 0.8, 1.8)  # above the crop's top row: in view, not in the crop
    assert beyond.in_view and not beyond.in_crop and beyond.height_px == 0.0


def test_visible_fraction_counts_the_box_pixels_at_the_boxs_depth():
    depth = np.full((300, 400), 50.0, np.float32)
    depth[200:220, 100:110] = 10.0  # the box's pixels at its depth
    depth[200:220, 110:120] = 4.0  # hidden behind something nearer
    assert visible_fraction(depth, (200, 220, 100, 120), 9.5, 10.5) == pytest.approx(0.5)
    assert visible_fraction(depth, (200, 200, 100, 120), 9.5, 10.5) == 0.0


def _obstacle(x, y, kind, name):
    return Obstacle(x, y, 0.0, 0.0, 0.8 if kind == PEDESTRIAN else 4.5, 0.8 if kind == PEDESTRIAN else 1.9, 0.0,
                    kind, None, name)


def test_the_nearest_participant_ahead_of_each_kind_with_bearing_positive_to_the_right():
    scene = [_obstacle(-3.0, 0.0, PEDESTRIAN, "behind"), _obstacle(12.0, -2.0, PEDESTRIAN, "right"),
             _obstacle(20.0, 1.0, PEDESTRIAN, "far"), _obstacle(8.0, 3.0, VEHICLE, "car")]
    found = nearest_ahead(scene, 0.0, 0.0, 0.0, PEDESTRIAN)  # car at the origin heading +x: y is to its left
    assert found.obstacle.name == "right" and found.bearing_deg == pytest.approx(math.degrees(math.atan2(2, 12)))
    assert nearest_ahead(scene, 0.0, 0.0, 0.0, VEHICLE).obstacle.name == "car"
    assert nearest_ahead(scene, 0.0, 0.0, math.pi, PEDESTRIAN).obstacle.name == "behind"  # turned round
    assert nearest_ahead([], 0.0, 0.0, 0.0, VEHICLE) is None


def _recorded(tmp_path, steps: int = 40, name: str = "crosser 1"):
    recorder = TelemetryRecorder(VIEW)
    depth = np.full((300, 400), 60.0, np.float32)
    for step in range(steps):
        gap = 20.0 - 0.5 * step  # a pedestrian coming closer
        recorder.add(step * 0.1, 5.0, 4, DriverStep(0.01 * step, 5.0, 4, 0), (0.0, 0.5, 0.0),
                     ExpertLabel(0.0, max(0.0, 5.0 - 0.2 * step), "pedestrian"),
                     [_obstacle(gap, 0.0, PEDESTRIAN, name)], (0.0, 0.0, 0.0), depth)
    path = tmp_path / "telemetry.npz"
    recorder.save(path)
    return recorder, path


def test_telemetry_is_compact_and_reads_back_at_its_columns_precision_with_nan_where_nothing_was(tmp_path):
    recorder, path = _recorded(tmp_path, steps=300)
    assert path.stat().st_size < 8000  # 30 s of driving
    read = load(path)
    assert len(read) == 300 and read.columns == tuple(column.name for column in COLUMNS)
    original = recorder.arrays()
    for index, column in enumerate(COLUMNS):
        values = read.column(column.name)
        assert np.array_equal(np.isnan(values), np.isnan(original[:, index])), column.name
        finite = ~np.isnan(values)
        assert np.allclose(values[finite], original[finite, index], atol=column.scale / 2 + 1e-9), column.name
    assert np.isnan(read.column("vehicle_distance_m")).all()  # no vehicle in the scene
    assert read.name_at("pedestrian", 10) == "crosser 1" and read.name_at("vehicle", 10) == ""
    assert read.column("expert_limit")[0] == telemetry.EXPERT_LIMITS.index("pedestrian")
    assert read.column("pedestrian_visible")[0] == 0.0  # the depth image shows nothing at its depth


def test_a_file_that_is_not_telemetry_is_refused(tmp_path):
    path = tmp_path / "other.npz"
    np.savez(path, something=np.zeros(3))
    with pytest.raises(ValueError, match="not a telemetry archive"):
        load(path)


def _episode(route: str, status: str, collision_type: str = "", actor: str | None = None) -> EpisodeResult:
    return EpisodeResult("msfsu", route, status, status == "success", 3.9, 40, 0.5, collision_type, 10.0, 30.0, 5.0,
                         0, collision_actor=actor)


def test_the_collision_page_names_who_was_hit_and_shows_the_last_seconds(tmp_path):
    _, path = _recorded(tmp_path)
    run = tmp_path / "run"
    target = telemetry_path(run, "msfsu", "abilities/pedestrian_left/train/00")
    target.parent.mkdir(parents=True)
    path.rename(target)
    records = {("msfsu", e.route): Record(run, e) for e in (
        _episode("abilities/pedestrian_left/train/00", "collision", "pedestrian", "pedestrian crossing from the left"),
        _episode("abilities/pedestrian_left/train/01", "collision", "pedestrian", "crosser 2"),  # no telemetry
        _episode("abilities/clear_road/train/00", "success"))}
    windows, missing = collision_windows(records, ["msfsu"])
    assert missing == 1 and len(windows) == 1
    (window,) = windows
    assert window.actor == "pedestrian crossing from the left"
    assert [step.before_s for step in window.steps] == [3.0, 2.5, 2.0, 1.5, 1.0, 0.5, 0.0]
    assert window.steps[-1].pedestrian.distance_m == pytest.approx(0.5, abs=0.01)  # 20 - 0.5 x 39
    page = collisions_markdown(windows, missing)
    assert "## msfsu on abilities/pedestrian_left/train/00, pedestrian: pedestrian crossing from the left" in page
    assert "1 collisions of these runs have no telemetry" in page
    assert "| 3.0 | 5.0 | 5.0 / 3.2 | 0.50 / 0.00 | crosser 1: 15.5 m at +0 deg, in crop" in page  # 3 s before the end
    assert where_before(window) == "in crop"  # 1 s before: straight ahead, 5.5 m
    assert "| msfsu | pedestrian | 1 | 0 | 0 | 1 | 0 | 0 |" in page  # never below 0.5 m/s
