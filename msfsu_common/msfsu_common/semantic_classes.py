"""The paper's five scene-understanding classes: ids, names and the colours every image and plot uses.

The one definition of the class list: the simulator's labels, the checkpoint's class names, synthetic
test scenes, segmentation overlays, videos and report plots all read it from here.
"""

from __future__ import annotations

from enum import IntEnum

import numpy as np


class SemanticClass(IntEnum):
    ROAD = 0  # drivable surface, crosswalks included
    ROAD_LINE = 1
    SIDEWALK = 2
    VEHICLE_OR_PEDESTRIAN = 3
    OTHER = 4


CLASS_NAMES: tuple[str, ...] = tuple(member.name.lower() for member in SemanticClass)
# Cityscapes-like, so overlays read familiar: road purple, line white, sidewalk pink, vehicle/pedestrian blue,
# other grey.
CLASS_COLOURS = np.array([(128, 64, 128), (255, 255, 255), (244, 35, 232), (0, 0, 142), (90, 90, 90)], np.uint8)
_PALETTE = np.vstack([CLASS_COLOURS, np.zeros((256 - len(CLASS_COLOURS), 3), np.uint8)])


def colourise(class_ids: np.ndarray) -> np.ndarray:
    """(H, W) uint8 class ids -> (H, W, 3) uint8 RGB; ids that are no class are drawn black."""
    return _PALETTE[np.asarray(class_ids, np.uint8)]


def overlay(rgb: np.ndarray, class_ids: np.ndarray, alpha: float = 0.5) -> np.ndarray:
    """Blend the class colours over an RGB image of the same size."""
    blended = (1.0 - alpha) * rgb.astype(np.float32) + alpha * colourise(class_ids).astype(np.float32)
    return blended.round().astype(np.uint8)
