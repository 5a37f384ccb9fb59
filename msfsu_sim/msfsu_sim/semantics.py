"""MetaDrive's Cityscapes colours -> the paper's 5 semantic classes (mono8 ids)."""

from __future__ import annotations

import numpy as np

from msfsu_common.semantic_classes import SemanticClass


# Colours MetaDrive's semantic camera draws (metadrive.constants.Semantics); anything else is OTHER (see
# COLOUR_TOLERANCE).
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


# The semantic pass draws flat colours, but not always the palette value exactly: MetaDrive's pedestrian
# comes out (211, 19, 58), its colour scaled by ~0.96 (measured; with exact matching every pedestrian pixel
# was labelled OTHER). A colour within this distance (per channel) of a palette colour takes its class. The
# palette colours are >= 46 apart per channel from each other and from MetaDrive's other classes (sky,
# terrain, fence, signs), so no colour is near two.
COLOUR_TOLERANCE = 12


def _build_lookup() -> np.ndarray:
    lookup = np.full(1 << 24, SemanticClass.OTHER, np.uint8)
    for (r, g, b), cls in CITYSCAPES_TO_CLASS.items():
        near = [np.arange(max(c - COLOUR_TOLERANCE, 0), min(c + COLOUR_TOLERANCE, 255) + 1, dtype=np.uint32)
                for c in (r, g, b)]
        lookup[(near[0][:, None, None] << 16) | (near[1][None, :, None] << 8) | near[2][None, None, :]] = cls
    return lookup


_LOOKUP = _build_lookup()


def colours_to_class_ids(rgb: np.ndarray) -> np.ndarray:
    """(H, W, 3) uint8 Cityscapes colours -> (H, W) uint8 class ids (one table lookup per pixel)."""
    pixels = rgb.astype(np.uint32)
    return _LOOKUP[(pixels[..., 0] << 16) | (pixels[..., 1] << 8) | pixels[..., 2]]
