"""Run-time fixes that make MetaDrive 0.4.3 render headless on Mesa llvmpipe (CPU OpenGL through EGL).

All of them in one place, applied by `apply()` before the engine starts; nothing in site-packages is
edited. On llvmpipe a 16x multisampled buffer is silently dropped (black or missing images) and
4x hangs, so every buffer is single-sampled; anisotropic filtering takes llvmpipe's slow path, so the
terrain textures are filtered at `ANISOTROPIC_DEGREE` (1x); the threaded render pipeline ("Cull") races with
reading buffers back on a CPU renderer, so `multi_thread_render` must be False in the env config
(`environment.py` sets it). MetaDrive's depth camera converts depth with a compute shader that uses
`texture2D` (rejected by Mesa's core profile) and writes an 8-bit log image; `cameras.MetricDepthCamera`
reads the depth buffer instead and never dispatches that shader.
"""

from __future__ import annotations

import functools
from typing import Any

from panda3d.core import loadPrcFileData

ANISOTROPIC_DEGREE = 1  # of every texture MetaDrive filters anisotropically: the terrain's, the sidewalk's
_applied = False


def _single_sampled(fbprops: Any) -> Any:
    if fbprops is not None:
        fbprops.set_multisamples(0)
    return fbprops


def _patch_filter_manager() -> None:
    """RGB camera and simplepbr render into a FilterManager buffer created with 16x MSAA."""
    from direct.filter.FilterManager import FilterManager

    original = FilterManager.render_scene_into

    @functools.wraps(original)
    def render_scene_into(self: Any, *args: Any, fbprops: Any = None, **kwargs: Any) -> Any:
        return original(self, *args, fbprops=_single_sampled(fbprops), **kwargs)

    FilterManager.render_scene_into = render_scene_into


def _patch_image_buffers() -> None:
    """Semantic camera passes its own 16x MSAA FrameBufferProperties to ImageBuffer."""
    from metadrive.engine.core.image_buffer import ImageBuffer

    original = ImageBuffer._create_buffer

    @functools.wraps(original)
    def _create_buffer(self: Any, width: int, height: int, frame_buffer_property: Any) -> Any:
        return original(self, width, height, _single_sampled(frame_buffer_property))

    ImageBuffer._create_buffer = _create_buffer


def _patch_terrain_filtering() -> None:
    """Terrain textures are loaded with a hard-coded 16x anisotropic filter."""
    from metadrive.engine.core.terrain import Terrain

    original = Terrain._load_mesh_terrain_textures

    @functools.wraps(original)
    def _load_mesh_terrain_textures(self: Any, engine: Any, *args: Any, **kwargs: Any) -> None:
        original(self, engine, *args, **kwargs)
        for texture in (self.grass_tex, self.grass_normal, self.grass_rough, self.rock_tex, self.rock_normal,
                        self.rock_rough, self.road_texture, self.road_texture_normal, self.road_texture_rough):
            texture.setAnisotropicDegree(ANISOTROPIC_DEGREE)

    Terrain._load_mesh_terrain_textures = _load_mesh_terrain_textures


def sidewalk_filtering(engine: Any, anisotropic_degree: int) -> None:
    """Set the anisotropic degree of the sidewalk texture every block draws (MetaDrive loads it with 8x).

    The texture pool hands every block the same `Texture`, so setting it on the pooled one sets it for the
    blocks of this map and of every later one.
    """
    from metadrive.engine.asset_loader import AssetLoader

    texture = engine.loader.loadTexture(AssetLoader.file_path("textures", "sidewalk", "color.png"))
    texture.setAnisotropicDegree(anisotropic_degree)


def skip_main_window_pass(engine: Any) -> None:
    """Stop drawing the hidden main window's scene (headless: no `main_camera` sensor, 1x1 window).

    simplepbr renders the scene through the engine's main camera (far plane 100 km: the whole map and all
    traffic) into a `filter-base` buffer every frame, and nothing reads it: on llvmpipe that pass costs
    more than all the sensor cameras together. The sensor cameras render from their own buffers.
    """
    if "main_camera" in engine.global_config["sensors"] or engine.pbrpipe is None:
        return
    for buffer in engine.pbrpipe.manager.buffers:
        buffer.set_active(False)
    engine.cam.node().set_active(False)


def reuse_terrain(engine: Any) -> None:
    """Rebuild the terrain only when the map changes, not on every reset.

    MetaDrive regenerates the terrain's height field and semantic textures from the map at each reset
    (mostly uploading two 2048x2048 textures); for the same map and centre they come
    out identical, so the terrain is only moved back into the world.
    """
    terrain = engine.terrain
    rebuild = terrain.reset
    built_for: list[tuple] = []

    def reset(center_point: Any) -> None:
        key = (id(engine.current_map), tuple(center_point))
        if built_for and built_for[0] == key:
            terrain.set_position(center_point)
            terrain.attach_to_world(engine.render, engine.physics_world)
            return
        rebuild(center_point)
        built_for[:] = [key]

    terrain.reset = reset


class _NoWarmUpFrames:
    """`engine.graphicsEngine` while MetaDrive's reset runs: its 5 warm-up frames are skipped."""

    def __init__(self, graphics_engine: Any) -> None:
        self._graphics_engine = graphics_engine

    def renderFrame(self) -> None:  # noqa: N802  Panda3D's name
        pass

    def __getattr__(self, name: str) -> Any:
        return getattr(self._graphics_engine, name)


def skip_reset_warm_up_frames(engine: Any) -> None:
    """MetaDrive renders 5 frames in every reset to settle its multi-threaded pipeline (and shadows).

    With `multi_thread_render=False` and no shadow pass they only cost time; the first frame
    of the episode is rendered after the cameras are mounted (SimEnvironment.reset).
    """
    reset = engine.reset

    @functools.wraps(reset)
    def reset_without_warm_up(*args: Any, **kwargs: Any) -> Any:
        graphics_engine = engine.graphicsEngine
        engine.graphicsEngine = _NoWarmUpFrames(graphics_engine)
        try:
            return reset(*args, **kwargs)
        finally:
            engine.graphicsEngine = graphics_engine

    engine.reset = reset_without_warm_up


def apply() -> None:
    """Install the fixes once per process (idempotent); call before the first env.reset()."""
    global _applied
    if _applied:
        return
    import metadrive.engine.core.engine_core  # noqa: F401  its class body loads the prc pages we override

    # Later prc pages win over the ones EngineCore loaded at import.
    loadPrcFileData("msfsu_sim llvmpipe", "framebuffer-multisample 0\nmultisamples 0\naudio-library-name null")
    _patch_filter_manager()
    _patch_image_buffers()
    _patch_terrain_filtering()
    _applied = True
