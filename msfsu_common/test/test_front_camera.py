"""camera_geometry.FrontCamera: the camera a bag names in its metadata, read back exactly, and anything else refused in
one line (msfsu-eval-bag reads it from bags it did not write)."""

import json

import pytest

from msfsu_common.camera_geometry import CameraView, FrontCamera

CARLA = FrontCamera(width=800, height=600, fov_deg=90.0, forward_m=2.0, right_m=0.0, up_m=2.0, pitch_deg=0.0)


def test_a_camera_reads_back_from_its_json_and_gives_the_view_with_a_crop():
    assert FrontCamera.from_json(CARLA.to_json()) == CARLA
    assert CARLA.view(0.5, 128, 128) == CameraView(800, 600, 2.0, 0.0, 2.0, 0.0, 90.0, 0.5, 128, 128)


@pytest.mark.parametrize("text, reason", [
    ("not json", "Expecting value"),
    ("[800, 600]", "needs exactly the fields"),
    (json.dumps({"width": 800}), "needs exactly the fields"),
    (json.dumps({**json.loads(CARLA.to_json()), "extra": 1}), "needs exactly the fields"),
    (json.dumps({**json.loads(CARLA.to_json()), "fov_deg": "wide"}), "could not convert"),
    (json.dumps({**json.loads(CARLA.to_json()), "fov_deg": 180.0}), "field of view 180.0 deg"),
    (json.dumps({**json.loads(CARLA.to_json()), "width": 0}), "0x600 pixels"),
    (json.dumps({**json.loads(CARLA.to_json()), "up_m": -1.0}), "-1.0 m above the road"),
])
def test_anything_else_is_one_line_naming_the_text(text, reason):
    with pytest.raises(ValueError) as raised:
        FrontCamera.from_json(text)
    message = str(raised.value)
    assert "\n" not in message and message.startswith("not a front camera (") and reason in message
