"""CARLA's semantic tags -> the paper's five classes, for the semantic camera carla-ros-bridge records (ROS-free).

The bridge converts the semantic camera with CARLA's CityScapes palette and publishes it as bgra8
(carla_ros_bridge/src/carla_ros_bridge/camera.py, SemanticSegmentationCamera); a raw semantic image carries the
tag in its red channel instead. CARLA numbered its tags twice: 0.9.10 - 0.9.13 have 23 tags (0.9.10 added
RailTrack, GuardRail, TrafficLight, Static, Dynamic, Water, Terrain), 0.9.14 - 0.9.15 took Cityscapes' ids, labels
and colours (29 tags; CHANGELOG 0.9.14). `CARLA_TAGS` is the one table: each tag by its CityObjectLabel name
(LibCarla/source/carla/rpc/ObjectLabel.h), its id and CityScapes colour in either numbering
(LibCarla/source/carla/image/CityScapesPalette.h) and the stack's class.

Palette colours mean the same tag in both numberings (only Fences and Terrain changed colour), so one colour
lookup serves every version; raw tags need the numbering named (`TAG_SETS`). A colour or tag that is no CARLA tag
gets `UNKNOWN`, never a class: the importer counts and reports it.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from functools import cache

import numpy as np

from msfsu_common.semantic_classes import SemanticClass

RGB = tuple[int, int, int]
UNKNOWN = 255  # a colour or tag that is no CARLA tag (no SemanticClass has this id)
LEGACY_TAGS, CITYSCAPES_TAGS = "0.9.10-0.9.13", "0.9.14-0.9.15"
TAG_SETS = (LEGACY_TAGS, CITYSCAPES_TAGS)

_ROAD, _LINE, _WALK = SemanticClass.ROAD, SemanticClass.ROAD_LINE, SemanticClass.SIDEWALK
_AGENT, _OTHER = SemanticClass.VEHICLE_OR_PEDESTRIAN, SemanticClass.OTHER


@dataclass(frozen=True)
class CarlaTag:
    """One CARLA semantic tag: its id and palette colour in each numbering (None: not a tag there)."""

    name: str  # CityObjectLabel (ObjectLabel.h; carla.CityObjectLabel in the Python API)
    legacy: tuple[int, RGB] | None  # 0.9.10 - 0.9.13
    cityscapes: tuple[int, RGB] | None  # 0.9.14 - 0.9.15
    stack_class: SemanticClass


CARLA_TAGS: tuple[CarlaTag, ...] = (
    #        name             0.9.10 - 0.9.13            0.9.14 - 0.9.15            class
    CarlaTag("None",          (0, (0, 0, 0)),            (0, (0, 0, 0)),            _OTHER),  # unlabeled
    CarlaTag("Roads",         (7, (128, 64, 128)),       (1, (128, 64, 128)),       _ROAD),
    CarlaTag("RoadLines",     (6, (157, 234, 50)),       (24, (157, 234, 50)),      _LINE),
    CarlaTag("Sidewalks",     (8, (244, 35, 232)),       (2, (244, 35, 232)),       _WALK),
    CarlaTag("Pedestrians",   (4, (220, 20, 60)),        (12, (220, 20, 60)),       _AGENT),
    CarlaTag("Vehicles",      (10, (0, 0, 142)),         None,                      _AGENT),
    CarlaTag("Rider",         None,                      (13, (255, 0, 0)),         _AGENT),
    CarlaTag("Car",           None,                      (14, (0, 0, 142)),         _AGENT),
    CarlaTag("Truck",         None,                      (15, (0, 0, 70)),          _AGENT),
    CarlaTag("Bus",           None,                      (16, (0, 60, 100)),        _AGENT),
    CarlaTag("Train",         None,                      (17, (0, 80, 100)),        _AGENT),
    CarlaTag("Motorcycle",    None,                      (18, (0, 0, 230)),         _AGENT),
    CarlaTag("Bicycle",       None,                      (19, (119, 11, 32)),       _AGENT),
    CarlaTag("Buildings",     (1, (70, 70, 70)),         (3, (70, 70, 70)),         _OTHER),
    CarlaTag("Fences",        (2, (100, 40, 40)),        (5, (190, 153, 153)),      _OTHER),
    CarlaTag("Other",         (3, (55, 90, 80)),         (22, (55, 90, 80)),        _OTHER),
    CarlaTag("Poles",         (5, (153, 153, 153)),      (6, (153, 153, 153)),      _OTHER),
    CarlaTag("Vegetation",    (9, (107, 142, 35)),       (9, (107, 142, 35)),       _OTHER),
    CarlaTag("Walls",         (11, (102, 102, 156)),     (4, (102, 102, 156)),      _OTHER),
    CarlaTag("TrafficSigns",  (12, (220, 220, 0)),       (8, (220, 220, 0)),        _OTHER),
    CarlaTag("Sky",           (13, (70, 130, 180)),      (11, (70, 130, 180)),      _OTHER),
    CarlaTag("Ground",        (14, (81, 0, 81)),         (25, (81, 0, 81)),         _OTHER),
    CarlaTag("Bridge",        (15, (150, 100, 100)),     (26, (150, 100, 100)),     _OTHER),
    CarlaTag("RailTrack",     (16, (230, 150, 140)),     (27, (230, 150, 140)),     _OTHER),
    CarlaTag("GuardRail",     (17, (180, 165, 180)),     (28, (180, 165, 180)),     _OTHER),
    CarlaTag("TrafficLight",  (18, (250, 170, 30)),      (7, (250, 170, 30)),       _OTHER),
    CarlaTag("Static",        (19, (110, 190, 160)),     (20, (110, 190, 160)),     _OTHER),
    CarlaTag("Dynamic",       (20, (170, 120, 50)),      (21, (170, 120, 50)),      _OTHER),
    CarlaTag("Water",         (21, (45, 60, 150)),       (23, (45, 60, 150)),       _OTHER),
    CarlaTag("Terrain",       (22, (145, 170, 100)),     (10, (152, 251, 152)),     _OTHER),
)


def _numbering(tag: CarlaTag, tag_set: str) -> tuple[int, RGB] | None:
    if tag_set not in TAG_SETS:
        raise ValueError(f"unknown CARLA tag numbering {tag_set!r} (known: {', '.join(TAG_SETS)})")
    return tag.legacy if tag_set == LEGACY_TAGS else tag.cityscapes


def _colour_key(r: np.ndarray | int, g: np.ndarray | int, b: np.ndarray | int) -> np.ndarray | int:
    return (r << 16) | (g << 8) | b


@cache
def _colour_lookup() -> np.ndarray:
    """(2**24,) uint8: 0xRRGGBB -> class id, UNKNOWN for a colour no tag of either numbering has."""
    lookup = np.full(1 << 24, UNKNOWN, np.uint8)
    for tag in CARLA_TAGS:
        for _, (r, g, b) in filter(None, (tag.legacy, tag.cityscapes)):
            key = _colour_key(r, g, b)
            if lookup[key] not in (UNKNOWN, tag.stack_class):
                raise AssertionError(f"colour {(r, g, b)} of {tag.name} already has another class")
            lookup[key] = tag.stack_class
    return lookup


@cache
def _tag_lookup(tag_set: str) -> np.ndarray:
    """(256,) uint8: raw tag id -> class id in one numbering, UNKNOWN for an id that is no tag there."""
    lookup = np.full(256, UNKNOWN, np.uint8)
    for tag in CARLA_TAGS:
        numbered = _numbering(tag, tag_set)
        if numbered is not None:
            lookup[numbered[0]] = tag.stack_class
    return lookup


@dataclass(frozen=True)
class Labels:
    """A semantic image as the stack's class ids, and what in it is no CARLA tag."""

    class_ids: np.ndarray  # (H, W) uint8 SemanticClass ids; UNKNOWN where `unknown` counts a pixel
    unknown: dict[RGB | int, int]  # colour (r, g, b) or raw tag id -> pixels; empty when every pixel is a tag


def palette_labels(rgb: np.ndarray) -> Labels:
    """(H, W, 3) uint8 CityScapes-palette colours, R, G, B -> class ids (one table lookup per pixel)."""
    pixels = rgb.astype(np.uint32)
    keys = _colour_key(pixels[..., 0], pixels[..., 1], pixels[..., 2])
    class_ids = _colour_lookup()[keys]
    unknown_keys, counts = np.unique(keys[class_ids == UNKNOWN], return_counts=True)
    unknown = {(int(key) >> 16, (int(key) >> 8) & 255, int(key) & 255): int(count)
               for key, count in zip(unknown_keys, counts)}
    return Labels(class_ids, unknown)


def tag_labels(tags: np.ndarray, tag_set: str) -> Labels:
    """(H, W) uint8 raw CARLA tag ids (the red channel of a raw semantic image) in numbering `tag_set` -> class ids."""
    class_ids = _tag_lookup(tag_set)[tags]
    unknown_tags, counts = np.unique(tags[class_ids == UNKNOWN], return_counts=True)
    return Labels(class_ids, {int(tag): int(count) for tag, count in zip(unknown_tags, counts)})



def is_palette_image(rgb: np.ndarray) -> bool:
    """(H, W, 3) uint8: every pixel a CityScapes palette colour of a CARLA tag, and some pixel with green or blue
    (a raw semantic image carries the tag in red, green and blue 0: read as colours, it is near black)."""
    return not palette_labels(rgb).unknown and bool(rgb[..., 1:].any())


def looks_like_raw_tags(colours: Iterable[RGB]) -> bool:
    """Colours that are a raw semantic image read as palette colours: red a tag id of some numbering, green and
    blue 0."""
    tag_ids = {numbered[0] for tag in CARLA_TAGS for numbered in (tag.legacy, tag.cityscapes) if numbered}
    return all(g == 0 and b == 0 and r in tag_ids for r, g, b in colours)
