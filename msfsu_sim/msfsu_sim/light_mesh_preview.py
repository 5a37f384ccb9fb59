"""The light meshes' preview: each traffic model in full beside each of its levels of detail, rendered offscreen, one
row per model (docs/images/sim/light_meshes.png).

    python -m msfsu_sim.light_mesh_preview docs/images/sim/light_meshes.png
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

import numpy as np

from msfsu_sim.light_meshes import CAR_LEVELS, LIGHT_MODELS, LightModel, _load, light_path, triangle_count
from msfsu_sim.metadrive_compat import egl_missing, metadrive_asset_dir


PREVIEW_TILE = (320, 240)
PREVIEW_DISTANCE = 2.2  # camera to model centre, in bounding-sphere radii (a car: ~6 m)


class _PreviewCamera:
    """An offscreen Panda3D buffer (EGL) with a sun, ambient light and a camera that frames one model per shot.

    Panda3D's per-pixel lighting, not the simulator's PBR pipeline: it shows the geometry and texture mapping of
    a model, not the simulator's exact look.
    """

    def __init__(self, width: int, height: int) -> None:
        from panda3d.core import (AmbientLight, Camera, DirectionalLight, FrameBufferProperties, GraphicsEngine,
                                  GraphicsOutput, GraphicsPipe, GraphicsPipeSelection, NodePath, PerspectiveLens,
                                  Texture, WindowProperties, loadPrcFileData)

        loadPrcFileData("msfsu light mesh preview",
                        "audio-library-name null\nframebuffer-multisample 0\nload-display p3headlessgl")
        self.width, self.height = width, height
        pipe = GraphicsPipeSelection.get_global_ptr().make_default_pipe()
        self.engine = GraphicsEngine.get_global_ptr()
        props = FrameBufferProperties()
        props.set_rgba_bits(8, 8, 8, 8)
        props.set_depth_bits(24)
        buffer = self.engine.make_output(pipe, "preview", 0, props, WindowProperties.size(width, height),
                                         GraphicsPipe.BF_refuse_window, None, None)
        if buffer is None:
            raise RuntimeError("no offscreen buffer (EGL): " + (egl_missing() or "?"))
        self.texture = Texture()
        buffer.add_render_texture(self.texture, GraphicsOutput.RTM_copy_ram)
        buffer.set_clear_color((0.75, 0.78, 0.8, 1))
        self.scene = NodePath("preview")
        self.scene.set_shader_auto()
        sun = self.scene.attach_new_node(DirectionalLight("sun"))
        sun.node().set_color((1.6, 1.6, 1.5, 1))
        sun.set_hpr(30, -45, 0)
        ambient = self.scene.attach_new_node(AmbientLight("ambient"))
        ambient.node().set_color((0.6, 0.6, 0.65, 1))
        self.scene.set_light(sun)
        self.scene.set_light(ambient)
        lens = PerspectiveLens()
        lens.set_fov(50)
        lens.set_aspect_ratio(width / height)
        self.camera = self.scene.attach_new_node(Camera("camera", lens))
        buffer.make_display_region().set_camera(self.camera)

    def shot(self, model: Any, scale: float) -> np.ndarray:
        """(H, W, 3) RGB of `model` at `scale`, seen from PREVIEW_DISTANCE bounding-sphere radii."""
        holder = self.scene.attach_new_node("holder")
        holder.set_scale(scale)
        model.instance_to(holder)
        low, high = holder.get_tight_bounds(self.scene)
        centre = (low + high) / 2
        distance = PREVIEW_DISTANCE * (high - low).length() / 2
        self.camera.set_pos(centre.x + 0.6 * distance, centre.y - 0.8 * distance, centre.z + 0.25 * distance)
        self.camera.look_at(centre)
        self.engine.render_frame()
        self.engine.render_frame()
        image = np.frombuffer(self.texture.get_ram_image_as("RGB"), np.uint8).reshape(self.height, self.width, 3)
        holder.remove_node()
        return image[::-1].copy()

    def close(self) -> None:
        self.engine.remove_all_windows()


def _preview_row(camera: _PreviewCamera, asset_dir: Path, model: LightModel) -> np.ndarray:
    """The full model, then each level of its light mesh forced, captioned; blank tiles pad to the car levels."""
    import cv2

    full = _load(asset_dir / "models" / model.source)
    tiles = [camera.shot(full, model.metadrive_scale)]
    light = _load(light_path(asset_dir, model.source))
    lods = light.find_all_matches("**/+LODNode")
    for level in range(len(model.levels) if lods.get_num_paths() else 0):
        lods[0].node().force_switch(level)
        tiles.append(camera.shot(light, model.metadrive_scale))
    if not lods.get_num_paths():
        tiles.append(camera.shot(light, model.metadrive_scale))
    while len(tiles) < 1 + len(CAR_LEVELS):
        tiles.append(np.full_like(tiles[0], 255))
    captions = [f"full {triangle_count(full)}"]
    captions += [f"level {i}: {100 * level.error_m:g} cm" for i, level in enumerate(model.levels)]
    for tile, caption in zip(tiles, captions):
        cv2.putText(tile, f"{model.source.split('/')[0]} {caption}", (6, 18), cv2.FONT_HERSHEY_SIMPLEX, 0.5,
                    (0, 0, 0), 1, cv2.LINE_AA)
    return np.hstack(tiles)


def render_preview(asset_dir: Path, out: Path) -> Path:
    """One PNG: a row per car (full model, then each level forced, at the same close distance) + pedestrian.

    Rendered offscreen with Panda3D's per-pixel lighting (not the simulator's PBR pipeline): it shows the
    geometry and texture mapping of each level, not the simulator's exact look.
    """
    import cv2

    camera = _PreviewCamera(*PREVIEW_TILE)
    rows = [_preview_row(camera, asset_dir, model) for model in LIGHT_MODELS if "tire" not in model.source]
    out.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(out), np.vstack(rows)[..., ::-1])
    camera.close()
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out", type=Path, help="the PNG")
    print(render_preview(metadrive_asset_dir(), parser.parse_args(argv).out))
    return 0


if __name__ == "__main__":
    sys.exit(main())
