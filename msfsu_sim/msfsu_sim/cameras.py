"""Front cameras of the ego car: RGB, metric depth and Cityscapes-coloured semantics, pixel-aligned.

All three share one lens (field of view, near/far) and one mount, so pixel (u, v) is the same ray in
every image. The depth camera reads the 32-bit float depth buffer and linearises it to metres along
the optical axis (CARLA's depth definition) instead of MetaDrive's 8-bit log image.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from metadrive.component.sensors.depth_camera import DepthCamera
from metadrive.component.sensors.rgb_camera import RGBCamera
from metadrive.component.sensors.semantic_camera import SemanticCamera
from metadrive.constants import CameraTagStateKey, Semantics
from metadrive.third_party.simplepbr import _load_shader_str
from panda3d.core import BitMask32, FrameBufferProperties, Shader, Texture, Vec3

RGB, DEPTH, SEMANTIC = "msfsu_rgb", "msfsu_depth", "msfsu_semantic"
LEAN_TERRAIN_SHADER = Path(__file__).with_name("shaders") / "terrain_rgb.frag.glsl"


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


class RGBDepthCamera(RGBCamera):
    """MetaDrive's RGB camera whose scene pass also keeps its depth buffer (32-bit float).

    The RGB image is the scene pass tone-mapped into this camera's buffer (as `RGBCamera`); metric depth
    is read from the same pass's depth attachment, so RGB and depth are pixel-aligned by construction and
    depth costs a read-back instead of a second render of the scene.
    """

    def _setup_effect(self) -> None:
        from direct.filter.FilterManager import FilterManager
        from metadrive.engine.core.terrain import Terrain

        cam = self.get_cam().node()
        cam.setTagStateKey(CameraTagStateKey.RGB)
        cam.setTagState(Semantics.TERRAIN.label,
                        Terrain.make_render_state(self.engine, "terrain.vert.glsl", "terrain.frag.glsl"))
        self.manager = FilterManager(self.buffer, self.cam)
        fbprops = FrameBufferProperties()
        fbprops.float_color = True
        fbprops.set_rgba_bits(16, 16, 16, 16)
        fbprops.set_depth_bits(32)
        fbprops.set_float_depth(True)
        fbprops.set_multisamples(0)  # llvmpipe: multisampled buffers are dropped (metadrive_compat)
        self.scene_tex = Texture("rgb scene")
        self.scene_tex.set_format(Texture.F_rgba16)
        self.scene_tex.set_component_type(Texture.T_float)
        self.depth_tex = Texture("rgb scene depth")
        self.depth_tex.set_format(Texture.F_depth_component32)
        self.depth_tex.set_component_type(Texture.T_float)
        self.tonemap_quad = self.manager.render_scene_into(colortex=self.scene_tex, depthtex=self.depth_tex,
                                                           fbprops=fbprops)
        shader = Shader.make(Shader.SL_GLSL, vertex=_load_shader_str("post.vert", {}),
                             fragment=_load_shader_str("tonemap.frag", {}))
        self.tonemap_quad.set_shader(shader)
        self.tonemap_quad.set_shader_input("tex", self.scene_tex)
        self.tonemap_quad.set_shader_input("exposure", 1.0)

    def depth_metres(self) -> np.ndarray:
        """(H, W) float32 metres along the optical axis of the last frame; no geometry reads the far plane."""
        return depth_texture_metres(self.engine, self.depth_tex, self.lens)


class MetricDepthCamera(DepthCamera):
    """Depth buffer -> (H, W) float32 metres; pixels without geometry (sky) read `far_m`."""

    def _dispatch_compute(self, task: Any) -> Any:
        return task.done  # the 8-bit log conversion (compute shader) is not used

    def get_rgb_array_cpu(self) -> np.ndarray:
        return depth_texture_metres(self.engine, self.depth_tex, self.lens)


class SemanticIdsCamera(SemanticCamera):
    """Cityscapes-coloured semantics whose background (sky) is drawn in the sky colour.

    MetaDrive clears every image buffer to white, the colour it also gives lane lines.
    """

    BKG_COLOR = Vec3(*(channel / 255.0 for channel in Semantics.SKY.color))


def depth_texture_metres(engine: Any, texture: Texture, lens: Any) -> np.ndarray:
    """A float depth texture of the last frame read back -> (H, W) float32 metres along `lens`'s axis."""
    engine.graphicsEngine.extractTextureData(texture, engine.win.get_gsg())
    buffer = np.frombuffer(texture.getRamImage().getData(), dtype=np.float32)
    window_depth = buffer.reshape(texture.getYSize(), texture.getXSize())[::-1]
    return linearize_depth(window_depth, lens.getNear(), lens.getFar())


def linearize_depth(window_depth: np.ndarray, near: float, far: float) -> np.ndarray:
    """OpenGL window depth in [0, 1] of a perspective lens -> distance along the optical axis (metres)."""
    ndc = window_depth.astype(np.float32) * 2.0 - 1.0
    return (2.0 * near * far / (far + near - ndc * (far - near))).astype(np.float32)


def sensor_config(width: int, height: int, labels: bool = True, depth_pass: bool = False) -> dict[str, tuple]:
    """MetaDrive `sensors` entries of the front cameras.

    RGB and depth come from one scene pass (`RGBDepthCamera`); `labels` adds the semantic pass (data
    collection); `depth_pass` renders depth separately instead (MetaDrive's way; the reference of the
    alignment test and the "before" of the simulator benchmark).
    """
    sensors = {RGB: (RGBDepthCamera, width, height)}
    if depth_pass:
        sensors[DEPTH] = (MetricDepthCamera, width, height)
    if labels:
        sensors[SEMANTIC] = (SemanticIdsCamera, width, height)
    return sensors


def mount_cameras(engine: Any, vehicle: Any, mount: CameraMount) -> None:
    """Attach the configured cameras to `vehicle` with one shared lens; call after every reset (new vehicle).

    The ego car is hidden from them: it is not in their view (the mount looks past the bonnet), but the
    cameras sit inside its bounds, so it is never culled and its model (~310k vertices) would be drawn by
    every pass of every frame.
    """
    hidden_from = BitMask32()
    for name in (RGB, DEPTH, SEMANTIC):
        if name not in engine.sensors:
            continue
        camera = engine.get_sensor(name)
        hidden_from |= camera.CAM_MASK
        camera.track(vehicle.origin, (mount.x, mount.y, mount.z), (0.0, mount.pitch_deg, 0.0))
        lens = camera.get_lens()
        lens.setFov(mount.fov_deg)  # horizontal; vertical follows the buffer's aspect ratio
        lens.setNearFar(mount.near_m, mount.far_m)
    vehicle.origin.hide(hidden_from)


def set_terrain_shader(engine: Any, fragment: Path | None) -> None:
    """Draw the terrain in the RGB camera with `fragment` (None: MetaDrive's terrain.frag.glsl).

    `LEAN_TERRAIN_SHADER` gives the same image as MetaDrive's shader while the PSSM shadow pass is off
    (`Quality.shadows`), with a fraction of its texture reads (the file says which and why).
    """
    from metadrive.engine.asset_loader import AssetLoader
    from metadrive.engine.core.terrain import Terrain
    from panda3d.core import NodePath

    if fragment is None:
        state = Terrain.make_render_state(engine, "terrain.vert.glsl", "terrain.frag.glsl")
    else:
        vertex = AssetLoader.file_path("../shaders", "terrain.vert.glsl")
        holder = NodePath("terrain shader")
        holder.set_shader(Shader.load(Shader.SL_GLSL, vertex, str(fragment)))
        state = holder.get_state()
    engine.get_sensor(RGB).get_cam().node().setTagState(Semantics.TERRAIN.label, state)


def set_active(engine: Any, active: bool) -> None:
    """Switch the front cameras' render passes on or off (off: nothing renders, images are not to be read)."""
    for name in (RGB, DEPTH, SEMANTIC):
        if name in engine.sensors:
            camera = engine.get_sensor(name)
            manager = getattr(camera, "manager", None)  # a FilterManager renders the scene into its own buffers
            for buffer in [camera.buffer, *(manager.buffers if manager is not None else ())]:
                buffer.set_active(active)


def read_rgb(engine: Any) -> np.ndarray:
    """(H, W, 3) uint8 RGB of the last frame."""
    return np.ascontiguousarray(engine.get_sensor(RGB).perceive(False)[..., ::-1])  # buffers are BGR


def read_depth(engine: Any) -> np.ndarray:
    """(H, W) float32 metres of the last frame (from the separate depth pass when there is one)."""
    if DEPTH in engine.sensors:
        return engine.get_sensor(DEPTH).get_rgb_array_cpu()
    return engine.get_sensor(RGB).depth_metres()


def read_semantic_colours(engine: Any) -> np.ndarray | None:
    """(H, W, 3) uint8 Cityscapes colours of the last frame, None without the semantic pass."""
    if SEMANTIC not in engine.sensors:
        return None
    return np.ascontiguousarray(engine.get_sensor(SEMANTIC).perceive(False)[..., ::-1])
