"""Towns, weathers and traffic levels of the datasets (fixed: the train/held-out split depends on them).

Towns are MetaDrive procedural maps pinned by block sequence and generator seed. Blocks: S straight,
C curve, X 4-way and T 3-way intersection. Training and held-out towns use different sequences (layouts),
like the paper's Town01 (train) / Town02 (test).
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Town:
    blocks: str
    map_seed: int
    lanes: int = 2


@dataclass(frozen=True)
class Weather:
    """What MetaDrive can vary without its render pipeline, plus image-space fog/wetness from depth/semantics."""

    sun_rgb: tuple[float, float, float]  # directional light colour (linear, 0..~1.5)
    sun_heading_deg: float
    sun_pitch_deg: float  # below the horizon is negative
    ambient: float  # ambient light level
    sky_tint: tuple[float, float, float]  # colour scale of the sky box
    fog_density: float  # 1/m, Beer-Lambert attenuation towards fog_rgb using metric depth
    fog_rgb: tuple[int, int, int]
    wetness: float  # 0 dry .. 1 soaked: darker, more saturated road surface


@dataclass(frozen=True)
class Traffic:
    vehicle_density: float  # MetaDrive traffic_density (vehicles per lane and ~10 m of road)
    walkers: int  # pedestrians on the sidewalks of the route
    crossers: int  # pedestrians crossing at the route's junctions


TRAIN_TOWNS: dict[str, Town] = {
    "town_a": Town("SXCTS", 11),
    "town_b": Town("CTSXC", 23),
    "town_c": Town("SCXCT", 37),
}
HELDOUT_TOWNS: dict[str, Town] = {
    "town_h1": Town("XCCTX", 101),
    "town_h2": Town("TSCXS", 211),
}
TOWNS = {**TRAIN_TOWNS, **HELDOUT_TOWNS}

TRAIN_WEATHERS: dict[str, Weather] = {
    "clear_noon": Weather((1.0, 1.0, 0.95), 30, -60, 0.25, (1.0, 1.0, 1.0), 0.0, (200, 200, 200), 0.0),
    "hazy_morning": Weather((1.0, 0.85, 0.7), 90, -20, 0.30, (1.0, 0.9, 0.8), 0.008, (215, 205, 190), 0.0),
    "wet_cloudy": Weather((0.6, 0.65, 0.7), 0, -70, 0.35, (0.7, 0.72, 0.75), 0.004, (170, 175, 180), 0.7),
    "clear_sunset": Weather((1.2, 0.7, 0.45), 250, -10, 0.20, (1.0, 0.7, 0.55), 0.0, (200, 160, 130), 0.0),
}
HELDOUT_WEATHERS: dict[str, Weather] = {
    "soft_rain_dusk": Weather((0.5, 0.5, 0.6), 200, -8, 0.25, (0.5, 0.5, 0.6), 0.01, (120, 120, 135), 0.9),
    "foggy_day": Weather((0.9, 0.9, 0.9), 120, -45, 0.40, (0.85, 0.85, 0.85), 0.025, (205, 205, 205), 0.3),
}
WEATHERS = {**TRAIN_WEATHERS, **HELDOUT_WEATHERS}

TRAFFIC: dict[str, Traffic] = {
    "empty": Traffic(0.0, 0, 0),
    "regular": Traffic(0.08, 6, 1),
    "dense": Traffic(0.2, 15, 3),
}
