"""infer_frame: the perception node's per-frame rules (depth validity, sizes, preprocessing, predict), no ROS."""

from __future__ import annotations

import numpy as np
import pytest

from msfsu_common.road_option import RoadOption
from msfsu_perception.frame_inference import infer_frame
from msfsu_perception.inference import DrivingModel
from msfsu_perception.preprocessing import InvalidDepthError, preprocess_frame

HEIGHT, WIDTH = 48, 64
RNG = np.random.default_rng(0)
RGB = RNG.integers(0, 255, (HEIGHT, WIDTH, 3), dtype=np.uint8)
DEPTH_M = RNG.uniform(1.0, 60.0, (HEIGHT, WIDTH)).astype(np.float32)


@pytest.fixture(scope="module")
def model(tiny_checkpoint) -> DrivingModel:
    return DrivingModel.from_checkpoint(tiny_checkpoint)


def test_a_frame_is_preprocessed_and_predicted_with_its_command_and_marks_each_stage(model):
    marks = []
    inferred = infer_frame(model, RGB, DEPTH_M, RoadOption.LEFT, mark=marks.append)
    expected = model.predict(preprocess_frame(RGB, DEPTH_M, model.preprocess), RoadOption.LEFT)
    assert (inferred.prediction.steer, inferred.prediction.target_speed) == (expected.steer, expected.target_speed)
    assert (inferred.prediction.class_ids == expected.class_ids).all()
    assert marks == ["preprocessed", "inferred"]
    assert inferred.depth_invalid_share == 0.0
    assert inferred.inputs.shape == (4, 64, 64)


def test_invalid_depth_pixels_up_to_the_threshold_are_read_as_far_and_more_reject_the_frame(model):
    holed = DEPTH_M.copy()
    holed[:12] = np.nan  # a quarter of the pixels
    far = DEPTH_M.copy()
    far[:12] = np.inf
    inferred = infer_frame(model, RGB, holed, RoadOption.LANE_FOLLOW)
    assert inferred.depth_invalid_share == 0.25
    assert inferred.prediction.steer == infer_frame(model, RGB, far, RoadOption.LANE_FOLLOW).prediction.steer
    with pytest.raises(InvalidDepthError):
        infer_frame(model, RGB, holed, RoadOption.LANE_FOLLOW, max_invalid_depth_fraction=0.2)
    with pytest.raises(InvalidDepthError):  # the default threshold: half the pixels
        infer_frame(model, RGB, np.full_like(DEPTH_M, np.nan), RoadOption.LANE_FOLLOW)


def test_depth_of_another_size_than_the_rgb_rejects_the_frame(model):
    with pytest.raises(ValueError, match="depth 30x20 does not match rgb 64x48"):
        infer_frame(model, RGB, DEPTH_M[:20, :30].copy(), RoadOption.LANE_FOLLOW)


def test_a_network_without_depth_ignores_the_depth_given(tmp_path):
    from msfsu_perception.checkpoint import save_checkpoint
    from msfsu_perception.model import MSFSUConfig, build_model
    from msfsu_perception.preprocessing import PreprocessConfig

    path = tmp_path / "su.pt"
    network = build_model(MSFSUConfig(variant="su", backbone="resnet18v2", input_height=64, input_width=64))
    save_checkpoint(path, network, PreprocessConfig(input_height=64, input_width=64, use_depth=False))
    rgb_only = DrivingModel.from_checkpoint(path)
    covered = np.full_like(DEPTH_M, np.nan)  # would reject the frame of a network that reads depth
    inferred = infer_frame(rgb_only, RGB, covered, RoadOption.RIGHT)
    assert inferred.depth_invalid_share is None and inferred.inputs.shape == (3, 64, 64)
    assert inferred.prediction.steer == infer_frame(rgb_only, RGB, None, RoadOption.RIGHT).prediction.steer
