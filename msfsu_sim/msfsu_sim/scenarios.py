"""Towns, weathers and traffic levels: the fixed, versioned conditions of data collection and benchmarks.

A town is a MetaDrive block sequence (S straight, C curve, X crossroad, T T-junction); the episode seed
picks that sequence's geometry, traffic and route. Training and held-out towns use different block
sequences and disjoint seed ranges (the paper: Town01 train, Town02 test). Weathers are what MetaDrive's
rasteriser can vary: sun direction and colour, ambient light, sky, fog.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Town:
    name: str
    blocks: str  # MetaDrive block sequence, each with junctions and curves
    first_seed: int  # seeds [first_seed, first_seed + SEEDS_PER_TOWN) belong to this town


@dataclass(frozen=True)
class Weather:
    name: str
    sun_heading_deg: float
    sun_pitch_deg: float  # elevation of the sun above the horizon
    sun_colour: tuple[float, float, float]
    ambient: float  # grey level of the ambient light
    sky: bool  # skybox, or a plain horizon colour
    fog_density: float  # exponential fog, 0 = none
    fog_colour: tuple[float, float, float] = (0.7, 0.7, 0.72)


@dataclass(frozen=True)
class Traffic:
    name: str
    vehicle_density: float  # MetaDrive traffic_density (vehicles per lane metre / 10)
    pedestrians: int


SEEDS_PER_TOWN = 1000
TRAINING_TOWNS = (
    Town("town_a", "SXSCTC", 0),
    Town("town_b", "CTSXCS", 1000),
)
HELD_OUT_TOWNS = (
    Town("town_c", "XCTCSX", 5000),
)
TRAINING_WEATHERS = (
    Weather("clear_noon", 40.0, 70.0, (1.0, 0.98, 0.92), 0.3, True, 0.0),
    Weather("clear_afternoon", 120.0, 35.0, (1.0, 0.92, 0.8), 0.25, True, 0.0),
    Weather("overcast", 0.0, 80.0, (0.55, 0.57, 0.6), 0.45, False, 0.004),
    Weather("clear_sunset", 250.0, 8.0, (1.0, 0.6, 0.35), 0.2, True, 0.0),
)
HELD_OUT_WEATHERS = (
    Weather("misty_morning", 80.0, 15.0, (0.85, 0.85, 0.9), 0.35, False, 0.02, (0.78, 0.8, 0.84)),
    Weather("dusk_haze", 300.0, 5.0, (0.8, 0.45, 0.3), 0.15, False, 0.012, (0.45, 0.38, 0.4)),
)
TRAFFIC_LEVELS = {
    "empty": Traffic("empty", 0.0, 0),
    "regular": Traffic("regular", 0.08, 6),
    "dense": Traffic("dense", 0.2, 15),
}
SPLITS = {"train": (TRAINING_TOWNS, TRAINING_WEATHERS), "validation": (HELD_OUT_TOWNS, HELD_OUT_WEATHERS)}


def by_name(items, name: str):
    """The town/weather called `name` (KeyError lists the known names)."""
    for item in items:
        if item.name == name:
            return item
    raise KeyError(f"unknown '{name}' (known: {', '.join(item.name for item in items)})")
