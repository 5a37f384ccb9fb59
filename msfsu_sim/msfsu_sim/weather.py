"""Visual conditions applied to a running MetaDrive engine: sun, ambient light, sky, fog.

Fog is attached to the RGB camera only: the semantic and depth cameras must keep exact colours and
distances whatever the weather.
"""

from __future__ import annotations

from typing import Any

from panda3d.core import Fog, FogAttrib, LVector4, RenderState

from msfsu_sim.cameras import RGB
from msfsu_sim.scenarios import Weather


def apply_weather(engine: Any, weather: Weather) -> None:
    light = engine.world_light
    light.direction_np.setHpr(weather.sun_heading_deg, -weather.sun_pitch_deg, 0.0)
    light.direction_np.node().setColor(LVector4(*weather.sun_colour, 1.0))
    light.ambient_np.node().setColor(LVector4(weather.ambient, weather.ambient, weather.ambient, 1.0))
    if engine.sky_box is not None:
        if weather.sky:
            engine.sky_box.origin.show()
        else:
            engine.sky_box.origin.hide()
    camera = engine.get_sensor(RGB).get_cam().node()
    state = RenderState.make_empty()
    if weather.fog_density > 0.0:
        fog = Fog(f"{weather.name}_fog")
        fog.setColor(*weather.fog_colour)
        fog.setExpDensity(weather.fog_density)
        state = RenderState.make(FogAttrib.make(fog))
    camera.setInitialState(state)
