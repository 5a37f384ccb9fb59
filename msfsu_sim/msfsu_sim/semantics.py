"""MetaDrive's Cityscapes colours -> the paper's five classes (0 road/lane, 1 road line, 2 sidewalk,
3 vehicle or pedestrian, 4 other). Crosswalk paint counts as road line (painted marking on the road)."""

from __future__ import annotations

import numpy as np
from metadrive.constants import Semantics

ROAD, ROAD_LINE, SIDEWALK, AGENT, OTHER = range(5)
COLOUR_TO_CLASS: dict[tuple[int, int, int], int] = {
    Semantics.ROAD.color: ROAD,
    Semantics.LANE_LINE.color: ROAD_LINE,
    Semantics.CROSSWALK.color: ROAD_LINE,
    Semantics.SIDEWALK.color: SIDEWALK,
    Semantics.CAR.color: AGENT,
    Semantics.TRUCK.color: AGENT,
    Semantics.BUS.color: AGENT,
    Semantics.PEDESTRIAN.color: AGENT,
    Semantics.BIKE.color: AGENT,
}


def _lookup_table() -> np.ndarray:
    """24-bit packed colour -> class id (everything unlisted: OTHER)."""
    table = np.full(1 << 24, OTHER, dtype=np.uint8)
    for (red, green, blue), class_id in COLOUR_TO_CLASS.items():
        table[(red << 16) | (green << 8) | blue] = class_id
    return table


_TABLE = _lookup_table()


def colours_to_classes(colours: np.ndarray) -> np.ndarray:
    """(H, W, 3) uint8 RGB Cityscapes colours -> (H, W) uint8 class ids, one table lookup per pixel."""
    packed = (colours[..., 0].astype(np.uint32) << 16) | (colours[..., 1].astype(np.uint32) << 8) | colours[..., 2]
    return _TABLE[packed]
