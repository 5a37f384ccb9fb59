"""A front camera's geometry (ROS-free, numpy only): where a box appears in the image and in the network's crop
(the closed-loop telemetry), and where a pixel with its depth lies around the car (the emergency brake).

A pinhole camera with the front cameras' mount (msfsu_sim.cameras.CameraMount: position in the vehicle frame, pitch,
horizontal field of view; square pixels) projects the corners of a participant's box. The part of the box's image
inside the camera image is "in view"; the part inside the rows the network keeps (msfsu_perception.preprocessing's
crop of the top rows) is "in the crop", with its size in the network's input pixels. Occlusion is not geometry: with
the depth image of the frame, `visible_fraction` counts the crop pixels of the box whose depth is the box's.
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass, fields

import numpy as np

HEIGHTS_M = {"pedestrian": 1.8, "vehicle": 1.5}  # box heights (MetaDrive's pedestrian and sedans)
DEPTH_TOLERANCE_M = 1.5  # a pixel belongs to the box when its depth is within this of the box's depth range


@dataclass(frozen=True)
class FrontCamera:
    """The front camera whose pixels the network and the emergency brake read: image size, lens and mount (vehicle
    frame: ahead of the vehicle's centre, right of its centre line, above the road; pitch negative looking down).
    A bag names its camera in its metadata (bag_schema.CAMERA, `to_json`): msfsu-collect the simulator's,
    msfsu-import-carla the one of the recording's sensor definition."""

    width: int
    height: int
    fov_deg: float  # horizontal
    forward_m: float
    right_m: float
    up_m: float
    pitch_deg: float

    def __post_init__(self) -> None:
        if not (self.width > 0 and self.height > 0 and 0 < self.fov_deg < 180 and -90 < self.pitch_deg < 90
                and self.up_m > 0):
            raise ValueError(f"no camera: {self.width}x{self.height} pixels, field of view {self.fov_deg} deg, "
                             f"pitch {self.pitch_deg} deg, {self.up_m} m above the road")

    def to_json(self) -> str:
        return json.dumps(asdict(self))

    @classmethod
    def from_json(cls, text: str) -> FrontCamera:
        """ValueError (one line) for anything that is not one camera's fields."""
        try:
            values = json.loads(text)
            names = {f.name for f in fields(cls)}
            if not isinstance(values, dict) or set(values) != names:
                raise ValueError(f"needs exactly the fields {', '.join(sorted(names))}")
            return cls(**{name: (int if name in ("width", "height") else float)(values[name]) for name in names})
        except (ValueError, TypeError) as error:
            raise ValueError(f"not a front camera ({error}): {text[:200]!r}") from None

    def view(self, crop_top_fraction: float, input_width: int, input_height: int) -> CameraView:
        """This camera with a network's crop and input size."""
        return CameraView(self.width, self.height, self.forward_m, self.right_m, self.up_m, self.pitch_deg,
                          self.fov_deg, crop_top_fraction, input_width, input_height)


@dataclass(frozen=True)
class CameraView:
    """The camera (image size, mount, lens) and the network's crop of its image."""

    width: int
    height: int
    forward_m: float  # mount: ahead of the vehicle's centre
    right_m: float
    up_m: float
    pitch_deg: float  # negative: looking down
    fov_deg: float  # horizontal
    crop_top_fraction: float  # rows removed from the top before the network
    input_width: int  # the network's input (after the crop's resize)
    input_height: int

    @property
    def focal_px(self) -> float:
        return self.width / 2 / math.tan(math.radians(self.fov_deg) / 2)

    def project(self, forward: np.ndarray, right: np.ndarray, up: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Vehicle-frame points (metres ahead of, right of and above the vehicle's centre on the ground) ->
        (column, row, depth along the optical axis); depth <= 0 is behind the camera."""
        x, y, z = forward - self.forward_m, right - self.right_m, up - self.up_m
        pitch = math.radians(self.pitch_deg)
        depth = x * math.cos(pitch) + z * math.sin(pitch)  # along the optical axis
        height = -x * math.sin(pitch) + z * math.cos(pitch)  # up in the camera
        safe = np.where(depth > 1e-3, depth, 1e-3)
        column = self.width / 2 + self.focal_px * y / safe
        row = self.height / 2 - self.focal_px * height / safe
        return column, row, depth

    def back_project(self, column: np.ndarray, row: np.ndarray, depth: np.ndarray) -> tuple[np.ndarray, np.ndarray,
                                                                                           np.ndarray]:
        """Pixels (column, row; pixel centres at +0.5) and their depth along the optical axis -> vehicle-frame points
        (ahead of, right of and above the vehicle's centre on the ground): the inverse of `project`."""
        pitch = math.radians(self.pitch_deg)
        y = (np.asarray(column) - self.width / 2) / self.focal_px * depth
        height = -(np.asarray(row) - self.height / 2) / self.focal_px * depth
        x = depth * math.cos(pitch) - height * math.sin(pitch)
        z = depth * math.sin(pitch) + height * math.cos(pitch)
        return x + self.forward_m, y + self.right_m, z + self.up_m

    def crop_pixel_centres(self, rows: int, columns: int) -> tuple[np.ndarray, np.ndarray]:
        """Camera (column, row) of the centre of each pixel of a (rows, columns) image of the network's crop (its
        segmentation), each (rows, columns)."""
        return crop_pixel_centres(self.width, self.height, self.crop_top_fraction, rows, columns)


def crop_pixel_centres(width: int, height: int, crop_top_fraction: float, rows: int,
                       columns: int) -> tuple[np.ndarray, np.ndarray]:
    """Camera (column, row) of the centre of each pixel of a (rows, columns) image of the crop of a width x height
    camera image without its top `crop_top_fraction` of rows (the network's segmentation), each (rows, columns)."""
    top = height * crop_top_fraction
    row = top + (np.arange(rows) + 0.5) * (height - top) / rows
    column = (np.arange(columns) + 0.5) * width / columns
    return np.meshgrid(column, row)


def depth_at_crop_pixels(depth: np.ndarray, crop_top_fraction: float, shape: tuple[int, int]) -> np.ndarray:
    """The camera's depth (H, W) at the centre of each pixel of a `shape` (rows, columns) image of its crop (the
    network's segmentation of the frame): (rows, columns), the camera pixel each centre falls in (what the emergency
    brake reads for each segmentation pixel; perception publishes it beside the segmentation)."""
    height, width = depth.shape
    column, row = crop_pixel_centres(width, height, crop_top_fraction, *shape)
    return depth[np.clip(row.astype(int), 0, height - 1), np.clip(column.astype(int), 0, width - 1)]


@dataclass(frozen=True)
class Appearance:
    in_view: bool  # some of the box is in the camera image
    in_crop: bool  # some of it is in the rows the network sees
    width_px: float  # its width and height in the network's input pixels (0 when not in the crop)
    height_px: float
    box: tuple[int, int, int, int] | None  # (top, bottom, left, right) camera pixels of its part in the crop


def appearance(view: CameraView, forward: float, right: float, heading: float, length: float, width: float,
               height: float) -> Appearance:
    """How a box (centre `forward`, `right` of the vehicle, `heading` rad relative to the vehicle's, counter-clockwise)
    appears: the bounding rectangle of its corners in front of the camera, clipped to the image and to the crop."""
    cos, sin = math.cos(heading), math.sin(heading)
    corners = [(forward + a * cos * length / 2 - b * sin * width / 2, right - a * sin * length / 2 - b * cos * width / 2)
               for a in (-1, 1) for b in (-1, 1)]
    f = np.array([c[0] for c in corners] * 2)
    r = np.array([c[1] for c in corners] * 2)
    u = np.array([0.0] * 4 + [height] * 4)
    column, row, depth = view.project(f, r, u)
    front = depth > 0.1
    if not front.any():
        return Appearance(False, False, 0.0, 0.0, None)
    left, right_px = float(column[front].min()), float(column[front].max())
    top, bottom = float(row[front].min()), float(row[front].max())
    if not front.all():  # part of it behind the camera: it reaches the image's edge on its side
        left, right_px = (0.0, right_px) if column[front].mean() < view.width / 2 else (left, float(view.width))
        bottom = float(view.height)
    left, right_px = max(left, 0.0), min(right_px, float(view.width))
    in_view = left < right_px and max(top, 0.0) < min(bottom, float(view.height))
    crop_top = view.height * view.crop_top_fraction
    crop_rows = (max(top, crop_top), min(bottom, float(view.height)))
    in_crop = in_view and crop_rows[0] < crop_rows[1]
    if not in_crop:
        return Appearance(in_view, False, 0.0, 0.0, None)
    scale_x = view.input_width / view.width
    scale_y = view.input_height / (view.height - crop_top)
    box = (int(crop_rows[0]), int(math.ceil(crop_rows[1])), int(left), int(math.ceil(right_px)))
    return Appearance(True, True, (right_px - left) * scale_x, (crop_rows[1] - crop_rows[0]) * scale_y, box)


def visible_fraction(depth_image: np.ndarray, box: tuple[int, int, int, int], near_m: float, far_m: float) -> float:
    """The share of the box's pixels whose depth lies within [near_m, far_m] (+- DEPTH_TOLERANCE_M): how much of it is
    not hidden behind something nearer (nor a hole seen through)."""
    top, bottom, left, right = box
    patch = depth_image[top:bottom, left:right]
    if patch.size == 0:
        return 0.0
    inside = (patch >= near_m - DEPTH_TOLERANCE_M) & (patch <= far_m + DEPTH_TOLERANCE_M)
    return float(np.count_nonzero(inside)) / patch.size
