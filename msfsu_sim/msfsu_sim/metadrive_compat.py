"""MetaDrive as this project uses it: the one version it is written for, where it is installed, and every patch.

Every change this project makes to MetaDrive's (and Panda3D's) code at run time is made here, and nothing in
site-packages is edited. Each patch is written for metadrive-simulator 0.4.3 (it replaces private methods
whose signatures change between versions), so `patch_classes` refuses any other version in one line. Patches
come in two kinds, applied in a fixed order relative to the engine (what an episode renders and simulates
depends on it):
- class patches, once per process, before the first engine is made: `patch_classes` (the headless llvmpipe
  fixes, then the light meshes' model paths);
- engine patches, on each new engine after `lazy_init`, in the order `SimEnvironment` calls them.
`applied()` lists every patch made in this process, in order.

Why the llvmpipe fixes (Mesa's CPU OpenGL through EGL): a 16x multisampled buffer is silently dropped (black or
missing images) and 4x hangs, so every buffer is single-sampled; anisotropic filtering takes llvmpipe's slow
path, so the terrain textures are filtered at `ANISOTROPIC_DEGREE` (1x); the threaded render pipeline ("Cull")
races with reading buffers back on a CPU renderer, so `multi_thread_render` must be False in the env config
(`environment.py` sets it). MetaDrive's depth camera converts depth with a compute shader that uses `texture2D`
(rejected by Mesa's core profile) and writes an 8-bit log image; `cameras.MetricDepthCamera` reads the depth
buffer instead and never dispatches that shader. The cameras, traffic and pedestrian managers are subclasses of
MetaDrive's, registered through the env config and `setup_engine`: no patch.

Nothing imports metadrive at this module's import (its `__init__` is slow): the asset tools use the names above
the patches without starting the simulator.
"""

from __future__ import annotations

import functools
import importlib.metadata
import importlib.util
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

METADRIVE_VERSION = "0.4.3"
METADRIVE_DISTRIBUTION = "metadrive-simulator"
ANISOTROPIC_DEGREE = 1  # of every texture MetaDrive filters anisotropically: the terrain's, the sidewalk's
_applied: list[str] = []  # patch names, in the order they were made
_classes_patched = False
_model_paths_redirected = False


def metadrive_asset_dir() -> Path:
    """Where MetaDrive 0.4.3 looks for assets (fixed: `<site-packages>/metadrive/assets`)."""
    spec = importlib.util.find_spec("metadrive")  # no import: metadrive's __init__ is slow
    if spec is None or not spec.submodule_search_locations:
        raise ModuleNotFoundError(f"{METADRIVE_DISTRIBUTION}=={METADRIVE_VERSION} is not installed")
    return Path(spec.submodule_search_locations[0]) / "assets"


def egl_missing() -> str | None:
    """Why headless rendering cannot work here (no EGL / Mesa driver), or None."""
    import ctypes.util

    if ctypes.util.find_library("EGL") is None:
        return "libEGL not found: install the Mesa EGL packages (apt-get install libegl1 libegl-mesa0 libgl1-mesa-dri)"
    return None


class MetaDriveVersionError(RuntimeError):
    """The installed MetaDrive is not the version the patches were written for (one line)."""


def check_metadrive_version(installed: str | None = None) -> None:
    """Raise MetaDriveVersionError unless `installed` (default: the installed distribution's) is METADRIVE_VERSION."""
    if installed is None:
        try:
            installed = importlib.metadata.version(METADRIVE_DISTRIBUTION)
        except importlib.metadata.PackageNotFoundError:
            installed = "none"
    if installed != METADRIVE_VERSION:
        raise MetaDriveVersionError(
            f"{METADRIVE_DISTRIBUTION} {installed} is installed, but msfsu_sim patches {METADRIVE_VERSION} only "
            f"(pip install {METADRIVE_DISTRIBUTION}=={METADRIVE_VERSION})")


def applied() -> list[str]:
    """Every patch made in this process, in order (an engine patch once per engine it was made on)."""
    return list(_applied)


# ------------------------------------------------------------------------------------------ class patches


def patch_classes(model_paths: Mapping[str, str] | None = None) -> None:
    """The class patches, once per process (idempotent), before the first engine is made.

    Checks the version first, then the llvmpipe fixes; with `model_paths` (source model path -> replacement, the
    light meshes: `light_meshes.model_paths`) also every model load through them.
    """
    global _classes_patched
    if not _classes_patched:
        check_metadrive_version()
        import metadrive.engine.core.engine_core  # noqa: F401  its class body loads the prc pages we override
        from panda3d.core import loadPrcFileData

        # Later prc pages win over the ones EngineCore loaded at import.
        loadPrcFileData("msfsu_sim llvmpipe", "framebuffer-multisample 0\nmultisamples 0\naudio-library-name null")
        _applied.append("prc: no multisampling, no audio")
        # Render and transform states freed when the last reference goes, not by Panda3D's periodic collection:
        # with it, what a frame drew differed in a few pixels from run to run when another process competed for
        # the CPU (two runs of one route in parallel), and a network fed those frames drove differently.
        loadPrcFileData("msfsu_sim states", "garbage-collect-states 0")
        _applied.append("prc: render states freed at once (no periodic collection)")
        _patch_filter_manager()
        _patch_image_buffers()
        _patch_terrain_filtering()
        _classes_patched = True
    if model_paths is not None:
        redirect_model_paths(model_paths)


def redirect_model_paths(replacements: Mapping[str, str]) -> None:
    """Make MetaDrive load `replacements[path]` wherever it would load `path` (once per process).

    Patches `AssetLoader.file_path`, the one function every vehicle, wheel and pedestrian model path goes through.
    """
    global _model_paths_redirected
    if _model_paths_redirected:
        return
    from metadrive.engine.asset_loader import AssetLoader

    replacements = dict(replacements)
    original = AssetLoader.file_path

    @functools.wraps(original)
    def file_path(*path_string: str, unix_style: bool = True) -> str:
        path = original(*path_string, unix_style=unix_style)
        return replacements.get(path, path)

    AssetLoader.file_path = staticmethod(file_path)
    _applied.append("AssetLoader.file_path: light meshes")
    _model_paths_redirected = True



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
    _applied.append("FilterManager.render_scene_into: single-sampled")


def _patch_image_buffers() -> None:
    """Semantic camera passes its own 16x MSAA FrameBufferProperties to ImageBuffer."""
    from metadrive.engine.core.image_buffer import ImageBuffer

    original = ImageBuffer._create_buffer

    @functools.wraps(original)
    def _create_buffer(self: Any, width: int, height: int, frame_buffer_property: Any) -> Any:
        return original(self, width, height, _single_sampled(frame_buffer_property))

    ImageBuffer._create_buffer = _create_buffer
    _applied.append("ImageBuffer._create_buffer: single-sampled")


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
    _applied.append("Terrain._load_mesh_terrain_textures: anisotropic degree")


# ----------------------------------------------------------------------------------------- engine patches


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
    _applied.append("engine: main window pass off")


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
    _applied.append("engine.terrain.reset: rebuilt only for a new map")


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
    _applied.append("engine.reset: no warm-up frames")


def time_tasks(engine: Any, timed: Callable[[Any], Any]) -> None:
    """Run the engine's tasks through `timed(task_manager)` (timing.TimedTaskManager: wall time per stage)."""
    engine.task_manager = timed(engine.task_manager)
    _applied.append("engine.task_manager: timed")


def renew_worlds_each_reset(engine: Any, renew: Callable[[Any], int]) -> None:
    """Call `renew(engine)` (physics_world.renew) in every reset, where MetaDrive has emptied the Bullet worlds:
    right after the engine's `_object_clean_check`; `engine.physics_world_moved_at_reset` keeps what it returned."""
    clean_check = engine._object_clean_check

    def clean_check_then_renew() -> None:
        clean_check()
        engine.physics_world_moved_at_reset = renew(engine)

    engine._object_clean_check = clean_check_then_renew
    _applied.append("engine._object_clean_check: new Bullet worlds")


def terrain_triangle_width(engine: Any, triangle_px: int) -> None:
    """Build the terrain's visual mesh with `triangle_px` wide triangles (MetaDrive hard-codes its default)."""
    from metadrive.engine.core.terrain import Terrain

    original = Terrain._generate_mesh_vis_terrain

    def generate(terrain, size, heightfield, attribute_tex, target_triangle_width=10, engine=None):
        return original(terrain, size, heightfield, attribute_tex, triangle_px, engine)

    engine.terrain._generate_mesh_vis_terrain = generate.__get__(engine.terrain)
    _applied.append("engine.terrain._generate_mesh_vis_terrain: triangle width")
