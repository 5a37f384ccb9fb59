"""MetaDrive as this project uses it: the one version it is written for and where that version is installed.

Nothing here imports metadrive (its `__init__` is slow): the asset tools and the light-mesh builder use these
names without starting the simulator.
"""

from __future__ import annotations

import importlib.util
from pathlib import Path

METADRIVE_VERSION = "0.4.3"


def metadrive_asset_dir() -> Path:
    """Where MetaDrive 0.4.3 looks for assets (fixed: `<site-packages>/metadrive/assets`)."""
    spec = importlib.util.find_spec("metadrive")  # no import: metadrive's __init__ is slow
    if spec is None or not spec.submodule_search_locations:
        raise ModuleNotFoundError(f"metadrive-simulator=={METADRIVE_VERSION} is not installed")
    return Path(spec.submodule_search_locations[0]) / "assets"


def egl_missing() -> str | None:
    """Why headless rendering cannot work here (no EGL / Mesa driver), or None."""
    import ctypes.util

    if ctypes.util.find_library("EGL") is None:
        return "libEGL not found: install the Mesa EGL packages (apt-get install libegl1 libegl-mesa0 libgl1-mesa-dri)"
    return None
