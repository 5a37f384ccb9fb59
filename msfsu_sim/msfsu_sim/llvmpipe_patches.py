"""Run-time fixes that make MetaDrive 0.4.3 render headless on Mesa llvmpipe (CPU OpenGL through EGL).

All of them in one place, applied by `apply()` before the engine starts; nothing in site-packages is
edited. Measured on llvmpipe (see FACTS.md): a 16x multisampled buffer is silently dropped (black or
missing images) and 4x hangs, so every buffer is single-sampled; 16x anisotropic filtering of the
terrain textures costs ~6.7 s per frame, 1x ~0.1 s; the threaded render pipeline ("Cull") races with
reading buffers back on a CPU renderer, so `multi_thread_render` must be False in the env config
(`environment.py` sets it). MetaDrive's depth camera converts depth with a compute shader that uses
`texture2D` (rejected by Mesa's core profile) and writes an 8-bit log image; `cameras.MetricDepthCamera`
reads the depth buffer instead and never dispatches that shader.
"""

from __future__ import annotations

import functools
from typing import Any

from panda3d.core import loadPrcFileData

ANISOTROPIC_DEGREE = 1
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
