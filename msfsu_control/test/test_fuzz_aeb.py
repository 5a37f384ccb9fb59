"""Fuzz (hypothesis): any segmentation, depth (NaN, infinite, negative included), speeds, steer and pose into the
emergency brake's core, with and without crossing prediction, give a decision without an exception: a known kind, a
target speed never above the network's (0 while braking), the same for the same frames, and a counted drop for a frame
it cannot judge."""

import dataclasses
import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from msfsu_common.camera_geometry import CameraView
from msfsu_control.aeb import BRAKE, DECISIONS, AebConfig, EmergencyBrake

CAMERA = CameraView(40, 30, 1.0, 0.0, 2.095, -2.0, 80.0, 0.5, 0, 0)
DEPTH = st.floats(-1.0, 200.0) | st.sampled_from([math.nan, math.inf, -math.inf, 0.0])
FRAME = st.tuples(arrays(np.uint8, (12, 16), elements=st.integers(0, 5)),
                  arrays(np.float32, (12, 16), elements=DEPTH.map(np.float32)),  # at the segmentation's pixels
                  st.floats(0, 20), st.floats(-1.0, 20.0), st.floats(-1.5, 1.5),
                  st.tuples(st.floats(-1e4, 1e4), st.floats(-1e4, 1e4), st.floats(-10, 10)) | st.none())


@settings(max_examples=200, deadline=None)
@given(st.lists(FRAME, min_size=1, max_size=12), st.booleans())
def test_any_frames_give_a_decision_within_the_networks_target(frames, predict_crossing):
    config = AebConfig(predict_crossing=predict_crossing, min_pixels=1)
    brake, again = EmergencyBrake(config), EmergencyBrake(config)
    for i, (segmentation, depth, speed, target, steer, pose) in enumerate(frames):
        decision = brake.step(0.05 * i, target, steer, speed, segmentation, depth, CAMERA, pose)
        assert decision.kind in DECISIONS
        assert decision.target_speed == 0.0 if decision.kind == BRAKE else decision.target_speed <= target
        assert decision.dropped in ("", "invalid_depth")
        repeated = again.step(0.05 * i, target, steer, speed, segmentation, depth, CAMERA, pose)
        assert dataclasses.astuple(repeated) == dataclasses.astuple(decision)
    assert sum(brake.decisions.values()) == len(frames)
