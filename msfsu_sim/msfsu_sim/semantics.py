"""MetaDrive's Cityscapes colours -> the paper's 5 semantic classes (mono8 ids)."""

from __future__ import annotations

from enum import IntEnum

import numpy as np


class SemanticClass(IntEnum):
    ROAD = 0  # drivable surface, crosswalks included
    ROAD_LINE = 1
    SIDEWALK = 2
    AGENT = 3  # vehicle or pedestrian
    OTHER = 4


# Colours MetaDrive's semantic camera draws (metadrive.constants.Semantics); anything else is OTHER.
CITYSCAPES_TO_CLASS: dict[tuple[int, int, int], SemanticClass] = {
    (128, 64, 128): SemanticClass.ROAD,
    (55, 176, 189): SemanticClass.ROAD,  # crosswalk
    (255, 255, 255): SemanticClass.ROAD_LINE,
    (244, 35, 232): SemanticClass.SIDEWALK,
    (0, 0, 142): SemanticClass.AGENT,  # car
    (0, 0, 70): SemanticClass.AGENT,  # truck
    (0, 60, 100): SemanticClass.AGENT,  # bus
    (220, 20, 60): SemanticClass.AGENT,  # pedestrian
    (119, 11, 32): SemanticClass.AGENT,  # bicycle
}
# Colours to draw class ids (docs, overlays): road purple, line white, sidewalk pink, agent blue, other grey.
CLASS_COLOURS = np.array([(128, 64, 128), (255, 255, 255), (244, 35, 232), (0, 0, 142), (90, 90, 90)], np.uint8)


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


def colourise(class_ids: np.ndarray) -> np.ndarray:
    """(H, W) class ids -> (H, W, 3) uint8 RGB for viewing."""
    return CLASS_COLOURS[np.minimum(class_ids, SemanticClass.OTHER)]
