"""Light meshes: levels of detail of MetaDrive's traffic models, built once with the assets.

MetaDrive draws every traffic car with its full model (7.7k-83k triangles plus four wheels of up to 2.8k
each) and every pedestrian with a 21.5k-triangle skinned mesh; on llvmpipe, vertex work runs on one
thread, so a few cars in view cost more than the rest of the frame. Here each model is simplified with
meshoptimizer (zeux's library, the one behind gltfpack): the simplifier only removes triangles and keeps a
subset of the original vertices, so normals, texture coordinates, tangents and skinning weights stay those
of the source model; unused vertices are then dropped. Cars and wheels get a Panda3D `LODNode` with a
level per distance band; the pedestrian (an animated `Character`) gets one light level. The levels are
written as `.bam` files under `<assets>/light/`, mirroring the source paths, and `use_light_meshes()` makes
MetaDrive's `AssetLoader.file_path` hand out the light file wherever one exists.

    msfsu-sim-assets                  # builds them (with the rest of the assets)
    python -m msfsu_sim.light_meshes  # rebuilds them, prints triangles per level
    python -m msfsu_sim.light_mesh_preview docs/images/sim/light_meshes.png  # full model vs each level
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from msfsu_sim.metadrive_compat import metadrive_asset_dir, redirect_model_paths

LIGHT_DIR = "light"  # under the asset folder
LIGHT_VERSION = "1"  # bump when the levels change: install_assets rebuilds them
CAR_MODELS = ("130", "beetle", "ferra", "lada", "truck")


@dataclass(frozen=True)
class Level:
    """One level of detail: simplified until the surface would move more than `error_m` metres, drawn up to
    `until_m` from the camera.

    The errors follow the pixel size of the cameras (80 deg field of view): a pixel spans 1.68 x distance /
    width, at 800 px wide 2.1 cm at 10 m, 5.3 cm at 25 m, 12.6 cm at 60 m; each level's error stays under a
    pixel from where it starts being drawn (400 px wide: under half a pixel).
    """

    error_m: float
    until_m: float


@dataclass(frozen=True)
class LightModel:
    source: str  # path under <assets>/models
    levels: tuple[Level, ...]  # nearest first; one level and no switching for animated models
    animated: bool = False
    metadrive_scale: float = 1.0  # the scale MetaDrive puts on the loaded model (its pedestrian is in cm)
    clustering: bool = True  # also try vertex clustering (crosses texture seams: smears a face's texture)


FAR_M = 100_000.0  # beyond any camera's far plane
CAR_LEVELS = (Level(0.01, 25.0), Level(0.04, 60.0), Level(0.10, FAR_M))
WHEEL_LEVELS = CAR_LEVELS
LIGHT_MODELS: tuple[LightModel, ...] = (
    *(LightModel(f"{car}/vehicle.gltf", CAR_LEVELS) for car in CAR_MODELS),
    *(LightModel(f"{car}/{wheel}.gltf", WHEEL_LEVELS) for car in CAR_MODELS
      for wheel in ("right_tire_front", "right_tire_back")),
    LightModel("pedestrian/scene.gltf", (Level(0.01, FAR_M),), animated=True, metadrive_scale=0.01,
               clustering=False),
)


def light_path(asset_dir: Path, source: str) -> Path:
    """Where the light version of `models/<source>` is written."""
    return asset_dir / LIGHT_DIR / Path(source).with_suffix(".bam")


def light_meshes_ready(asset_dir: Path) -> bool:
    version_file = asset_dir / LIGHT_DIR / "version.txt"
    return version_file.is_file() and version_file.read_text().strip() == LIGHT_VERSION


# ---------------------------------------------------------------------------------------------- geometry


def _rows(array: Any) -> np.ndarray:
    """A GeomVertexArrayData as a (rows, stride) uint8 array (a copy)."""
    stride = array.get_array_format().get_stride()
    return np.frombuffer(array.get_handle().get_data(), np.uint8).reshape(-1, stride)


def _positions(vdata: Any) -> np.ndarray:
    """float32 (rows, 3) of the `vertex` column."""
    fmt = vdata.get_format()
    index = fmt.get_array_with("vertex")
    column = fmt.get_array(index).get_column("vertex")
    if column.get_numeric_type() != column.NT_float32 or column.get_num_components() < 3:
        raise ValueError(f"vertex column is {column}, expected 3 float32")
    start = column.get_start()
    return np.ascontiguousarray(_rows(vdata.get_array(index))[:, start:start + 12]).view(np.float32)


def _triangle_indices(geom: Any) -> np.ndarray:
    """uint32 triangle list of all of a Geom's primitives (strips and fans decomposed)."""
    from panda3d.core import Geom

    _INDEX_DTYPES = {int(Geom.NT_uint8): np.uint8, int(Geom.NT_uint16): np.uint16, int(Geom.NT_uint32): np.uint32}
    parts = []
    for k in range(geom.get_num_primitives()):
        primitive = geom.get_primitive(k).decompose()
        if primitive.get_num_vertices_per_primitive() != 3:
            raise ValueError(f"{primitive.get_class_type()} is not triangles")
        if not primitive.is_indexed():
            primitive = primitive.make_copy()
            primitive.make_indexed()
        dtype = _INDEX_DTYPES[int(primitive.get_index_type())]
        parts.append(np.frombuffer(primitive.get_vertices().get_handle().get_data(), dtype).astype(np.uint32))
    return np.concatenate(parts) if parts else np.zeros(0, np.uint32)


def simplify_indices(indices: np.ndarray, positions: np.ndarray, error: float, clustering: bool = True) -> np.ndarray:
    """A triangle list over the same vertices that moves no surface more than `error` (relative to these
    positions' extent, meshoptimizer's convention), with as few triangles as that allows.

    The topology-preserving simplifier cannot collapse across attribute seams, and these models are mostly
    seams (hard-edged normals, triangle soups from OBJ conversion), so vertex clustering (the "sloppy"
    simplifier) under the same error bound is tried on its result and kept where it is smaller (unless
    `clustering` is off: clustering merges vertices across texture seams).
    """
    import meshoptimizer

    out = np.zeros(len(indices), np.uint32)
    count = meshoptimizer.simplify(out, indices, positions, target_index_count=0, target_error=error)
    result = out[:count].copy()
    if clustering:
        sloppy = np.zeros(len(indices), np.uint32)
        sloppy_count = meshoptimizer.simplify_sloppy(sloppy, result, positions, target_index_count=0,
                                                     target_error=error)
        if 3 <= sloppy_count < count:
            result = sloppy[:sloppy_count].copy()
    cache_ordered = np.zeros_like(result)
    meshoptimizer.optimize_vertex_cache(cache_ordered, result, vertex_count=len(positions))
    return cache_ordered


def simplified_geom(geom: Any, error: float, clustering: bool = True) -> Any:
    """A copy of `geom` simplified to `error` (in its own positions' units) with only the vertices it uses."""
    from panda3d.core import Geom, GeomTriangles, GeomVertexData, SparseArray, TransformBlendTable

    vdata = geom.get_vertex_data()
    import meshoptimizer

    positions = _positions(vdata)
    relative = error / max(float(meshoptimizer.simplify_scale(positions)), 1e-9)
    indices = simplify_indices(_triangle_indices(geom), positions, relative, clustering)
    used, remapped = np.unique(indices, return_inverse=True)
    light = GeomVertexData(vdata)  # same format, blend table and animation: only rows are dropped
    light.unclean_set_num_rows(len(used))
    for index in range(vdata.get_num_arrays()):
        light.modify_array_handle(index).set_data(_rows(vdata.get_array(index))[used].tobytes())
    if vdata.get_transform_blend_table() is not None:  # skinned: the table names the rows it animates
        table = TransformBlendTable(vdata.get_transform_blend_table())
        table.set_rows(SparseArray.range(0, len(used)))
        light.set_transform_blend_table(table)
    triangles = GeomTriangles(vdata.get_usage_hint())
    index_type = Geom.NT_uint16 if len(used) < 65535 else Geom.NT_uint32
    triangles.set_index_type(index_type)
    handle = triangles.modify_vertices(len(remapped)).modify_handle()
    handle.set_data(remapped.astype(np.uint16 if index_type == Geom.NT_uint16 else np.uint32).tobytes())
    out = Geom(light)
    out.add_primitive(triangles)
    return out


def triangle_count(root: Any) -> int:
    total = 0
    for path in root.find_all_matches("**/+GeomNode"):
        node = path.node()
        for i in range(node.get_num_geoms()):
            geom = node.get_geom(i)
            total += sum(geom.get_primitive(k).get_num_faces() for k in range(geom.get_num_primitives()))
    return total


def _simplify_tree(root: Any, error_m: float, model: LightModel) -> None:
    """Replace every Geom under `root` (in place) by its simplification to `error_m` metres.

    Model files keep their vertices in their own units under scaling nodes (glTF's centimetre models):
    the error is converted with each GeomNode's scale relative to `root` and the scale MetaDrive puts on
    the model (0.01 for the pedestrian; the cars' 0.8-1.1 is left out).
    """
    for path in root.find_all_matches("**/+GeomNode"):
        node = path.node()
        scale = path.get_transform(root).get_scale()
        units_per_m = 3.0 / max(model.metadrive_scale * (abs(scale[0]) + abs(scale[1]) + abs(scale[2])), 1e-12)
        for i in range(node.get_num_geoms()):
            node.set_geom(i, simplified_geom(node.get_geom(i), error_m * units_per_m, model.clustering))


# ---------------------------------------------------------------------------------------------- models


def _loader() -> Any:
    """Panda3D's model loader with the glTF plugin registered (no window, no ShowBase)."""
    from direct.showbase.Loader import Loader as PythonLoader  # registers Python file types (panda3d-gltf)
    from panda3d.core import Loader

    PythonLoader._loadPythonFileTypes()
    return Loader.get_global_ptr()


def _load(path: Path) -> Any:
    from panda3d.core import Filename, LoaderOptions, NodePath

    node = _loader().load_sync(Filename.from_os_specific(str(path)), LoaderOptions(LoaderOptions.LF_no_cache))
    if node is None:
        raise OSError(f"Panda3D cannot load {path}")
    return NodePath(node)


def build_light_model(source: Path, model: LightModel) -> tuple[Any, list[int]]:
    """The light version of one model (a NodePath to write) and its triangles: the source's, then per level."""
    from panda3d.core import LODNode, ModelRoot, NodePath

    original = _load(source)
    full = triangle_count(original)
    if model.animated:
        _simplify_tree(original, model.levels[0].error_m, model)
        return original, [full, triangle_count(original)]
    root = NodePath(ModelRoot(original.get_name()))
    lod = LODNode("msfsu_light_lod")
    lod_path = root.attach_new_node(lod)
    counts = [full]
    near = 0.0
    for level_index, level in enumerate(model.levels):
        level_path = lod_path.attach_new_node(f"level{level_index}")
        copy = original.copy_to(NodePath())
        for child in copy.get_children():
            child.reparent_to(level_path)
        _simplify_tree(level_path, level.error_m, model)
        level_path.flatten_strong()  # one draw call per material where the parts allow
        lod.add_switch(level.until_m, near)
        near = level.until_m
        counts.append(triangle_count(level_path))
    return root, counts


def build_light_meshes(asset_dir: Path, progress: bool = True) -> dict[str, list[int]]:
    """Write every light model under `<asset_dir>/light/` (version file last); triangles per model and level."""
    from tqdm import tqdm

    out_dir = asset_dir / LIGHT_DIR
    (out_dir / "version.txt").unlink(missing_ok=True)
    counts: dict[str, list[int]] = {}
    for model in tqdm(LIGHT_MODELS, desc="light meshes", unit="model", disable=not progress):
        source = asset_dir / "models" / model.source
        built, counts[model.source] = build_light_model(source, model)
        target = light_path(asset_dir, model.source)
        target.parent.mkdir(parents=True, exist_ok=True)
        if not built.write_bam_file(str(target)):
            raise OSError(f"cannot write {target}")
    (out_dir / "version.txt").write_text(LIGHT_VERSION + "\n")
    return counts


# ---------------------------------------------------------------------------------------------- run time

def model_paths(asset_dir: Path | None = None) -> dict[str, str]:
    """Source model path -> its light model, as MetaDrive's `AssetLoader.file_path` returns them. Raises if the
    light meshes were not built (run `msfsu-sim-assets`)."""
    asset_dir = asset_dir or metadrive_asset_dir()
    if not light_meshes_ready(asset_dir):
        raise FileNotFoundError(f"light meshes missing under {asset_dir / LIGHT_DIR}: run msfsu-sim-assets")
    models = asset_dir / "models"
    return {str(models / model.source): str(light_path(asset_dir, model.source)) for model in LIGHT_MODELS}


def use_light_meshes(asset_dir: Path | None = None) -> None:
    """Make MetaDrive load the light model wherever one was built (once per process, before models load;
    the patch is metadrive_compat.redirect_model_paths)."""
    redirect_model_paths(model_paths(asset_dir))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description="Rebuild the light meshes (levels of detail) of the traffic models")
    parser.parse_args(argv)
    counts = build_light_meshes(metadrive_asset_dir())
    for source, levels in counts.items():
        print(f"{source}: {levels[0]} triangles -> " + " / ".join(str(n) for n in levels[1:]))
    return 0


if __name__ == "__main__":
    sys.exit(main())
