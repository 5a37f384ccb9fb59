"""Offline asset folder for MetaDrive 0.4.3, built from registry packages only.

MetaDrive 0.4.x downloads its 3D assets from GitHub at the first reset, which fails offline. The
0.3.0.1 wheel on PyPI carries most of them: we unpack those, move car models to the paths 0.4.3
expects, generate the terrain textures/heightfield 0.3.0.1 lacks, and write `version.txt` last so an
interrupted build is redone (and MetaDrive never tries to download).
"""

from __future__ import annotations

import argparse
import shutil
import subprocess
import sys
import tempfile
import zipfile
from pathlib import Path

import cv2
import numpy as np

from msfsu_sim.light_meshes import CAR_MODELS, build_light_meshes, light_meshes_ready
from msfsu_sim.metadrive_compat import METADRIVE_VERSION, egl_missing, metadrive_asset_dir

ASSET_WHEEL_VERSION = "0.3.0.1"
CACHE_DIR = Path.home() / ".cache" / "msfsu_sim"
# Folders of the 0.3.0.1 wheel that 0.4.3 never reads (logos kept: the engine loads one at start).
SKIPPED = ("waymo", "real_data", "carla")


def assets_ready(asset_dir: Path | None = None) -> bool:
    version_file = (asset_dir or metadrive_asset_dir()) / "version.txt"
    return version_file.is_file() and version_file.read_text().strip() == METADRIVE_VERSION


def _asset_wheel(cache_dir: Path) -> Path:
    """The 0.3.0.1 wheel, downloaded once into the cache through pip (the configured package index)."""
    cache_dir.mkdir(parents=True, exist_ok=True)
    pattern = f"metadrive_simulator-{ASSET_WHEEL_VERSION}-*.whl"
    found = sorted(cache_dir.glob(pattern))
    if not found:
        subprocess.run(
            [sys.executable, "-m", "pip", "download", "--no-deps", "--quiet",
             f"metadrive-simulator=={ASSET_WHEEL_VERSION}", "-d", str(cache_dir)],
            check=True,
        )
        found = sorted(cache_dir.glob(pattern))
    return found[0]


def _extract(wheel: Path, target: Path) -> None:
    prefix = "metadrive/assets/"
    with zipfile.ZipFile(wheel) as archive:
        for name in archive.namelist():
            relative = name[len(prefix):]
            if not name.startswith(prefix) or name.endswith("/") or relative.split("/")[0] in SKIPPED:
                continue
            destination = target / relative
            destination.parent.mkdir(parents=True, exist_ok=True)
            destination.write_bytes(archive.read(name))
    for car in CAR_MODELS:  # 0.3.0.1: models/vehicle/<car>/, 0.4.3: models/<car>/
        shutil.move(str(target / "models" / "vehicle" / car), str(target / "models" / car))


def _smooth_noise(rng: np.random.Generator, size: int, octaves: tuple[int, ...]) -> np.ndarray:
    """Sum of bicubically upsampled random grids (value noise) in [0, 1], float32 (size, size)."""
    total = np.zeros((size, size), np.float32)
    for cells in octaves:
        grid = rng.random((cells, cells), dtype=np.float32)
        total += cv2.resize(grid, (size, size), interpolation=cv2.INTER_CUBIC) / cells**0.5
    total -= total.min()
    return total / max(float(total.max()), 1e-6)


def _normal_map(height: np.ndarray, strength: float) -> np.ndarray:
    """Tangent-space normal map (OpenGL convention, RGB uint8) of a height image."""
    dy, dx = np.gradient(height * strength)
    normal = np.dstack([-dx, -dy, np.ones_like(height)])
    normal /= np.linalg.norm(normal, axis=2, keepdims=True)
    return ((normal * 0.5 + 0.5) * 255).astype(np.uint8)


def _material(rng: np.random.Generator, size: int, base_rgb: tuple[int, int, int], contrast: float,
              octaves: tuple[int, ...]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(colour RGB, normal RGB, roughness grey) uint8 textures of a noisy material."""
    height = _smooth_noise(rng, size, octaves)
    grain = rng.random((size, size), dtype=np.float32)
    shade = 1.0 + contrast * (height - 0.5) + 0.5 * contrast * (grain - 0.5)
    colour = np.clip(np.asarray(base_rgb, np.float32) * shade[..., None], 0, 255).astype(np.uint8)
    rough = np.clip(200 + 40 * (grain - 0.5), 0, 255).astype(np.uint8)
    return colour, _normal_map(height + 0.3 * grain, 4.0), rough


def _write_rgb(path: Path, rgb: np.ndarray) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    if not cv2.imwrite(str(path), rgb[..., ::-1] if rgb.ndim == 3 else rgb):
        raise OSError(f"cannot write {path}")


def _generate_textures(target: Path, seed: int = 0) -> None:
    """Textures 0.4.3's terrain shader samples but the 0.3.0.1 wheel lacks (names fixed by terrain.py)."""
    rng = np.random.default_rng(seed)
    textures = target / "textures"
    grass, grass_normal, grass_rough = _material(rng, 1024, (86, 120, 52), 0.5, (8, 32, 128))
    _write_rgb(textures / "grass1" / "GroundGrassGreen002_COL_1K.jpg", grass)
    _write_rgb(textures / "grass1" / "GroundGrassGreen002_NRM_1K.jpg", grass_normal)
    _write_rgb(textures / "grass2" / "grass_path_2_rough_1k.png", grass_rough)
    rock, rock_normal, rock_rough = _material(rng, 1024, (112, 92, 70), 0.6, (8, 32, 128))
    _write_rgb(textures / "rock" / "brown_mud_leaves_01_diff_1k.png", rock)
    _write_rgb(textures / "rock" / "brown_mud_leaves_01_nor_gl_1k.png", rock_normal)
    _write_rgb(textures / "rock" / "brown_mud_leaves_01_rough_1k.png", rock_rough)
    # terrain.py reshapes the asphalt colour to (2048, 2048, 3) to paint crosswalks on it.
    asphalt, asphalt_normal, asphalt_rough = _material(rng, 2048, (78, 78, 82), 0.25, (16, 64, 256))
    _write_rgb(textures / "asphalt" / "diff_2k.png", asphalt)
    _write_rgb(textures / "asphalt" / "normal_2k.png", asphalt_normal)
    _write_rgb(textures / "asphalt" / "rough_2k.png", asphalt_rough)
    # 16-bit heightfield, 2048x2048 = 1 px per metre of the 2048 m terrain: gentle hills around the map.
    hills = _smooth_noise(rng, 2048, (4, 8, 16, 32))
    _write_rgb(textures / "terrain" / "heightfield.png", (hills * 30000).astype(np.uint16))


def install_assets(cache_dir: Path = CACHE_DIR, asset_dir: Path | None = None, force: bool = False) -> Path:
    """Build the asset folder (and its light meshes) if missing or stale; returns its path. Safe to call
    repeatedly."""
    asset_dir = asset_dir or metadrive_asset_dir()
    if force or not assets_ready(asset_dir):
        _install_base_assets(cache_dir, asset_dir)
    if force or not light_meshes_ready(asset_dir):
        build_light_meshes(asset_dir)
    return asset_dir


def _install_base_assets(cache_dir: Path, asset_dir: Path) -> None:
    wheel = _asset_wheel(cache_dir)
    with tempfile.TemporaryDirectory(dir=asset_dir.parent) as staging:
        build = Path(staging) / "assets"
        _extract(wheel, build)
        _generate_textures(build)
        (build / "version.txt").write_text(METADRIVE_VERSION + "\n")
        if asset_dir.exists():
            shutil.rmtree(asset_dir)
        build.rename(asset_dir)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cache-dir", type=Path, default=CACHE_DIR, help="where the 0.3.0.1 wheel is kept")
    parser.add_argument("--force", action="store_true", help="rebuild even if the folder is complete")
    args = parser.parse_args(argv)
    was_ready = assets_ready() and light_meshes_ready(metadrive_asset_dir())
    path = install_assets(args.cache_dir, force=args.force)
    state = "already present" if was_ready and not args.force else "built"
    print(f"MetaDrive {METADRIVE_VERSION} assets {state}: {path}")
    problem = egl_missing()
    if problem:
        print(f"WARNING: {problem}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
