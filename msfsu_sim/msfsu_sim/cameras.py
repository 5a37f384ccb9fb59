"""Front cameras of the ego car: RGB, metric depth and Cityscapes-coloured semantics, pixel-aligned.

All three share one lens (field of view, near/far) and one mount, so pixel (u, v) is the same ray in
every image. The depth camera reads the 32-bit float depth buffer and linearises it to metres along
the optical axis (CARLA's depth definition) instead of MetaDrive's 8-bit log image.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from metadrive.component.sensors.depth_camera import DepthCamera
from metadrive.component.sensors.rgb_camera import RGBCamera
from metadrive.component.sensors.semantic_camera import SemanticCamera
from metadrive.constants import Semantics
from panda3d.core import Vec4
from metadrive.constants import Semantics
from panda3d.core import Vec3

RGB, DEPTH, SEMANTIC = "msfsu_rgb", "msfsu_depth", "msfsu_semantic"


@dataclass(frozen=True)
class CameraMount:
    """Pose in the vehicle frame (x right, y forward, z up; metres, degrees) and lens."""

    x: float = 0.0
    y: float = 1.0  # front of the car (MetaDrive's default sensor sits at 0.8 m)
    z: float = 1.5
    pitch_deg: float = -2.0
    fov_deg: float = 80.0
    near_m: float = 0.5
    far_m: float = 100.0  # beyond the depth range the network uses (50 m); fewer objects to draw


class SkySemanticCamera(SemanticCamera):
    """MetaDrive clears the semantic buffer to white, the lane-line colour: clear to Cityscapes sky."""

    BKG_COLOR = Vec4(*(channel / 255 for channel in Semantics.SKY.color), 1.0)


class MetricDepthCamera(DepthCamera):
    """Depth buffer -> (H, W) float32 metres; pixels without geometry (sky) read `far_m`."""

    def _dispatch_compute(self, task: Any) -> Any:
        return task.done  # the 8-bit log conversion (compute shader) is not used

    def get_rgb_array_cpu(self) -> np.ndarray:
        self.engine.graphicsEngine.extractTextureData(self.depth_tex, self.engine.win.get_gsg())
        buffer = np.frombuffer(self.depth_tex.getRamImage().getData(), dtype=np.float32)
        window_depth = buffer.reshape(self.depth_tex.getYSize(), self.depth_tex.getXSize())[::-1]
        return linearize_depth(window_depth, self.lens.getNear(), self.lens.getFar())


class SemanticIdsCamera(SemanticCamera):
    """Cityscapes-coloured semantics whose background (sky) is drawn in the sky colour.

    MetaDrive clears every image buffer to white, the colour it also gives lane lines.
    """

    BKG_COLOR = Vec3(*(channel / 255.0 for channel in Semantics.SKY.color))


def linearize_depth(window_depth: np.ndarray, near: float, far: float) -> np.ndarray:
    """OpenGL window depth in [0, 1] of a perspective lens -> distance along the optical axis (metres)."""
    ndc = window_depth.astype(np.float32) * 2.0 - 1.0
    return (2.0 * near * far / (far + near - ndc * (far - near))).astype(np.float32)


def sensor_config(width: int, height: int) -> dict[str, tuple]:
    """MetaDrive `sensors` entries of the three front cameras."""
    return {RGB: (RGBCamera, width, height), DEPTH: (MetricDepthCamera, width, height),
            SEMANTIC: (SemanticIdsCamera, width, height)}


def mount_cameras(engine: Any, vehicle: Any, mount: CameraMount) -> None:
    """Attach the cameras to `vehicle` with one shared lens; call after every reset (new vehicle)."""
    for name in (RGB, DEPTH, SEMANTIC):
        camera = engine.get_sensor(name)
        camera.track(vehicle.origin, (mount.x, mount.y, mount.z), (0.0, mount.pitch_deg, 0.0))
        lens = camera.get_lens()
        lens.setFov(mount.fov_deg)  # horizontal; vertical follows the buffer's aspect ratio
        lens.setNearFar(mount.near_m, mount.far_m)


def read_cameras(engine: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(rgb (H, W, 3) uint8, depth (H, W) float32 m, Cityscapes colours (H, W, 3) uint8) of the last frame."""
    rgb = engine.get_sensor(RGB).perceive(False)[..., ::-1]  # buffers are BGR
    depth = engine.get_sensor(DEPTH).get_rgb_array_cpu()
    semantic = engine.get_sensor(SEMANTIC).perceive(False)[..., ::-1]
    return np.ascontiguousarray(rgb), depth, np.ascontiguousarray(semantic)
