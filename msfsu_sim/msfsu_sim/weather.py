"""Weather in the simulator (ROS-free helpers of msfsu_sim.environment): the sun, ambient light and sky of a Weather,
fog in image space along the metric depth, and a wet road's asphalt texture."""

from __future__ import annotations

from typing import Any

import numpy as np

from msfsu_sim.scenarios import Weather


def apply_fog(rgb: np.ndarray, depth: np.ndarray, weather: Weather) -> np.ndarray:
    """Fog in image space: Beer-Lambert attenuation towards the fog colour along the metric depth."""
    if weather.fog_density <= 0:
        return rgb
    transmittance = np.exp(-weather.fog_density * depth)[..., None]
    out = rgb * transmittance + np.asarray(weather.fog_rgb, np.float32) * (1 - transmittance)
    return np.clip(out, 0, 255).astype(np.uint8)


def wet_road_texture(dry: np.ndarray, wetness: float) -> np.ndarray:
    """Asphalt texels (H, W, C) uint8 of a wet road: darker and bluer (C is B, G, R as Panda3D stores it)."""
    tint = np.array([10, 4, 0], np.float32)[: dry.shape[-1]] * wetness
    return np.clip(dry * (1 - 0.45 * wetness) + tint, 0, 255).astype(np.uint8)


def apply_weather(engine: Any, weather: Weather, wet_textures: dict[float, Any]) -> None:
    """Light, sky and road surface of `weather` on the engine (`wet_textures`: wetness -> asphalt texture, the
    engine's cache)."""
    light = engine.world_light
    light.direction_np.node().setColor((*weather.sun_rgb, 1.0))
    light.direction_np.setHpr(weather.sun_heading_deg, weather.sun_pitch_deg, 0)
    light.ambient_np.node().setColor((weather.ambient,) * 3 + (1.0,))
    if engine.sky_box is not None:
        engine.sky_box.origin.setColorScale(*weather.sky_tint, 1.0)
    terrain = engine.terrain
    if getattr(terrain, "_mesh_terrain", None) is not None:
        terrain._mesh_terrain.set_shader_input("road_tex", road_texture(terrain.road_texture, weather, wet_textures))


def road_texture(dry: Any, weather: Weather, cache: dict[float, Any]) -> Any:
    """The terrain's asphalt texture for `weather` (the dry one, or a darker, bluer copy; cached)."""
    if weather.wetness <= 0:
        return dry
    if weather.wetness not in cache:
        texels = np.frombuffer(dry.getRamImage().getData(), np.uint8)
        channels = dry.getNumComponents()
        wet = dry.makeCopy()
        wet.setRamImage(wet_road_texture(texels.reshape(-1, channels), weather.wetness).tobytes())
        cache[weather.wetness] = wet
    return cache[weather.wetness]
