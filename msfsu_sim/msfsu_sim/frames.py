"""Example frames of the simulator as PNGs (RGB, metric depth, 5-class ids) for docs and benchmarks."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from msfsu_sim.environment import Observation
from msfsu_common.semantic_classes import colourise


def depth_colours(depth: np.ndarray, max_m: float = 80.0) -> np.ndarray:
    """(H, W) metres -> (H, W, 3) RGB, log scale so near structure stays visible."""
    scaled = np.log1p(np.clip(depth, 0, max_m)) / np.log1p(max_m)
    return cv2.applyColorMap((255 * (1 - scaled)).astype(np.uint8), cv2.COLORMAP_INFERNO)[..., ::-1]


def save_frames(obs: Observation, directory: Path, prefix: str) -> list[Path]:
    """`<prefix>_rgb.png`, `_depth.png` and (when rendered) `_semantic.png` of one observation."""
    directory.mkdir(parents=True, exist_ok=True)
    images = {"rgb": obs.rgb, "depth": depth_colours(obs.depth)}
    if obs.semantic_ids is not None:
        images["semantic"] = colourise(obs.semantic_ids)
    paths = []
    for name, rgb in images.items():
        path = directory / f"{prefix}_{name}.png"
        cv2.imwrite(str(path), np.ascontiguousarray(rgb[..., ::-1]), [cv2.IMWRITE_PNG_COMPRESSION, 9])
        paths.append(path)
    return paths
