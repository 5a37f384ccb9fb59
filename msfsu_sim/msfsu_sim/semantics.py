"""MetaDrive's Cityscapes colours -> the paper's 5 semantic classes (mono8 ids)."""

from __future__ import annotations

import numpy as np

from msfsu_common.semantic_classes import SemanticClass


# Colours MetaDrive's semantic camera draws (metadrive.constants.Semantics); anything else is OTHER.
CITYSCAPES_TO_CLASS: dict[tuple[int, int, int], SemanticClass] = {
    (128, 64, 128): SemanticClass.ROAD,
    (55, 176, 189): SemanticClass.ROAD,  # crosswalk
    (255, 255, 255): SemanticClass.ROAD_LINE,
    (244, 35, 232): SemanticClass.SIDEWALK,
    (0, 0, 142): SemanticClass.VEHICLE_OR_PEDESTRIAN,  # car
    (0, 0, 70): SemanticClass.VEHICLE_OR_PEDESTRIAN,  # truck
    (0, 60, 100): SemanticClass.VEHICLE_OR_PEDESTRIAN,  # bus
    (220, 20, 60): SemanticClass.VEHICLE_OR_PEDESTRIAN,  # pedestrian
    (119, 11, 32): SemanticClass.VEHICLE_OR_PEDESTRIAN,  # bicycle
}


def _build_lookup() -> np.ndarray:
    lookup = np.full(1 << 24, SemanticClass.OTHER, np.uint8)
    for (r, g, b), cls in CITYSCAPES_TO_CLASS.items():
        lookup[(r << 16) | (g << 8) | b] = cls
    return lookup


_LOOKUP = _build_lookup()


def colours_to_class_ids(rgb: np.ndarray) -> np.ndarray:
    """(H, W, 3) uint8 Cityscapes colours -> (H, W) uint8 class ids (one table lookup per pixel)."""
    pixels = rgb.astype(np.uint32)
    return _LOOKUP[(pixels[..., 0] << 16) | (pixels[..., 1] << 8) | pixels[..., 2]]
