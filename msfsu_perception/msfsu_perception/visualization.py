"""Colours for the paper's five segmentation classes (Cityscapes-like, so overlays read familiar)."""

from __future__ import annotations

import numpy as np

CLASS_NAMES = ("road", "road_line", "sidewalk", "vehicle_or_pedestrian", "other")
CLASS_PALETTE = np.array(
    [[128, 64, 128], [255, 255, 255], [244, 35, 232], [0, 0, 142], [70, 70, 70]], dtype=np.uint8
)


def colorize(class_ids: np.ndarray) -> np.ndarray:
    """(H, W) class ids -> (H, W, 3) uint8 RGB; ids outside the palette are drawn black."""
    palette = np.vstack([CLASS_PALETTE, np.zeros((256 - len(CLASS_PALETTE), 3), np.uint8)])
    return palette[class_ids]


def overlay(rgb: np.ndarray, class_ids: np.ndarray, alpha: float = 0.5) -> np.ndarray:
    """Blend the class colours over an RGB image of the same size."""
    blended = (1.0 - alpha) * rgb.astype(np.float32) + alpha * colorize(class_ids).astype(np.float32)
    return blended.round().astype(np.uint8)
