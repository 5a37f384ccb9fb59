"""Light meshes: the simplifier on known geometry, and the built levels of MetaDrive's models."""

import numpy as np
import pytest

from msfsu_sim import light_meshes
from msfsu_sim.light_meshes import CAR_LEVELS, LIGHT_MODELS, simplify_indices


def _grid(n: int, bump: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """An n x n vertex grid over the unit square (z = bump x a smooth hill), as a triangle list."""
    xs, ys = np.meshgrid(np.linspace(0, 1, n), np.linspace(0, 1, n))
    zs = bump * np.sin(np.pi * xs) * np.sin(np.pi * ys)
    positions = np.stack([xs, ys, zs], -1).reshape(-1, 3).astype(np.float32)
    cells = np.arange(n * n).reshape(n, n)[:-1, :-1].reshape(-1)
    quads = np.stack([cells, cells + 1, cells + n, cells + 1, cells + n + 1, cells + n], -1)
    return quads.reshape(-1).astype(np.uint32), positions


def test_a_flat_grid_collapses_to_a_few_triangles_over_its_own_vertices():
    indices, positions = _grid(40)
    light = simplify_indices(indices, positions, error=1e-3)
    assert len(light) % 3 == 0 and 2 * 3 <= len(light) <= 8 * 3  # 3,042 triangles -> a handful
    assert set(light.tolist()) <= set(range(len(positions)))
    triangles = positions[light.reshape(-1, 3)]
    area = 0.5 * np.linalg.norm(np.cross(triangles[:, 1] - triangles[:, 0], triangles[:, 2] - triangles[:, 0]), axis=1)
    assert area.sum() == pytest.approx(1.0, rel=1e-3)  # still covers the square


def test_a_curved_surface_keeps_more_triangles_the_smaller_the_error():
    indices, positions = _grid(40, bump=0.2)
    counts = [len(simplify_indices(indices, positions, error)) // 3 for error in (0.0, 0.002, 0.01, 0.05)]
    assert counts[0] > 0.99 * len(indices) // 3  # no error allowed: only the flat border can go
    assert counts[0] > counts[1] > counts[2] > counts[3] > 0


def test_without_clustering_texture_seams_are_never_crossed():
    """Two halves of a surface share positions along x = 0.5 but not vertices (a texture seam): the
    topology-preserving simplifier keeps the seam, vertex clustering may merge across it."""
    indices, positions = _grid(21, bump=0.1)
    seam_x = positions[:, 0] > 0.5 + 1e-6
    right = positions.copy()
    offset = len(positions)
    both = np.vstack([positions, right])
    tri = indices.reshape(-1, 3)
    on_right = seam_x[tri].all(1) | (seam_x[tri].any(1) & (positions[tri][:, :, 0].mean(1) > 0.5))
    split = np.where(on_right[:, None], tri + offset, tri).reshape(-1).astype(np.uint32)
    light = simplify_indices(split, both, error=0.05, clustering=False).reshape(-1, 3)
    assert not ((light < offset).any(1) & (light >= offset).any(1)).any()  # no triangle uses both copies


@pytest.fixture(scope="module")
def asset_dir():
    from msfsu_sim.assets import install_assets

    return install_assets()


def test_every_model_has_its_light_file_with_fewer_triangles_per_level(asset_dir):
    assert light_meshes.light_meshes_ready(asset_dir)
    for model in LIGHT_MODELS:
        full = light_meshes.triangle_count(light_meshes._load(asset_dir / "models" / model.source))
        light = light_meshes._load(light_meshes.light_path(asset_dir, model.source))
        lods = light.find_all_matches("**/+LODNode")
        if model.animated:
            assert lods.get_num_paths() == 0 and light.find("**/+Character")
            assert light_meshes.triangle_count(light) < full / 4, model.source
            continue
        lod = lods[0].node()
        assert lod.get_num_switches() == len(model.levels) == lod.get_num_children()
        # Panda3D: a level switches "in" at its far distance and "out" at its near one
        assert [lod.get_in(i) for i in range(lod.get_num_switches())] == [level.until_m for level in model.levels]
        counts = [light_meshes.triangle_count(lods[0].get_child(i)) for i in range(lod.get_num_children())]
        assert counts == sorted(counts, reverse=True) and counts[0] <= full, model.source
    assert CAR_LEVELS[0].until_m >= 20.0  # full detail where a car fills a good part of the image


def test_metadrive_loads_the_light_car_and_the_animated_pedestrian(asset_dir):
    from direct.actor.Actor import Actor
    from metadrive.engine.asset_loader import AssetLoader

    light_meshes.use_light_meshes(asset_dir)
    AssetLoader.asset_path = asset_dir
    assert AssetLoader.file_path("models", "lada/vehicle.gltf").endswith("light/lada/vehicle.bam")
    assert AssetLoader.file_path("models", "lada", "right_tire_front.gltf").endswith("light/lada/right_tire_front.bam")
    assert AssetLoader.file_path("models", "box.bam") == str(asset_dir / "models" / "box.bam")  # no light version
    walker = Actor(AssetLoader.file_path("models", "pedestrian", "scene.gltf"))
    try:
        control = walker.get_anim_control("Take 001")
        assert control is not None and control.get_num_frames() > 1
        control.loop(True)
        control.pose(control.get_num_frames() // 2)  # animating the compacted, re-tabled vertices
        walker.update(force=True)
        assert light_meshes.triangle_count(walker) < 21506 / 4
    finally:
        walker.cleanup()
