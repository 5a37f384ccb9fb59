"""The ego vehicle's front camera from a carla_spawn_objects definition file (ROS-free).

The file the recording's sensors were spawned with (`objects_definition_file`; docs/carla.md's recipe saves it as
RECIPE_OBJECTS) says where the camera sits and what its lens is; the recording does not (the recipe records no
/tf). The import writes that camera into the output's metadata (bag_schema.CAMERA), so the emergency brake of
`msfsu-eval-bag` places pixels with the recording's own camera. CARLA's vehicle frame: x ahead, y right, z up from
the vehicle's origin on the ground (a vehicle actor's origin is the bottom centre of its bounding box); a camera's
pitch is positive looking up.

Two layouts of the file are read, as the bridge's revisions wrote them:
- carla_spawn_objects' `{"objects": [..., {"type": "vehicle.*", "id": "<role>", "sensors": [...]}]}`, the
  vehicle's sensors listed under its `sensors` (or nested under its own `objects`), each with a `spawn_point`;
- carla_ego_vehicle's `{"sensors": [...]}`: the vehicle's sensors alone (its role was the launch's), each with its
  pose as `x`, `y`, `z`, `roll`, `pitch`, `yaw` beside the other attributes (or a `spawn_point`).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from msfsu_common.camera_geometry import FrontCamera
from msfsu_sim.carla.recording import CarlaImportError

RECIPE_OBJECTS = Path("msfsu_objects.json")  # the name docs/carla.md saves its sensor definition under


def sensor_id(topic: str) -> str:
    """The bridge's sensor id of a camera topic: /carla/<role>/<sensor id>/image."""
    return topic.rstrip("/").split("/")[-2]


def _listed(value: Any, what: str) -> list[dict[str, Any]]:
    if not isinstance(value, list) or not all(isinstance(item, dict) for item in value):
        raise TypeError(f"{what} is no list of objects")
    return value


def read_definition(path: Path) -> dict[str, list[dict[str, Any]]]:
    """The `objects` or `sensors` list of a definition file (module doc); CarlaImportError (one line) for a file that
    is none."""
    try:
        document = json.loads(path.read_text())
        if not isinstance(document, dict) or not {"objects", "sensors"} & set(document):
            raise ValueError("it lists neither 'objects' nor 'sensors'")
        return {key: _listed(document[key], repr(key)) for key in ("objects", "sensors") if key in document}
    except OSError as error:
        raise CarlaImportError(f"cannot read the sensor definition {path} ({error.strerror or error}): give the "
                               "carla_spawn_objects file the recording's sensors were spawned with (--objects FILE; "
                               "docs/carla.md)") from None
    except (ValueError, KeyError, TypeError) as error:
        raise CarlaImportError(f"{path} is no carla_spawn_objects definition ({{\"objects\": [...]}} or "
                               f"{{\"sensors\": [...]}}): {error}") from None


def vehicle_sensors(path: Path, role: str) -> dict[str, dict[str, Any]]:
    """The sensors of vehicle `role` in definition file `path`, by id (either layout, module doc); CarlaImportError if
    it defines no such vehicle."""
    definition = read_definition(path)
    if "objects" not in definition:  # carla_ego_vehicle's file: one vehicle's sensors
        listed = definition["sensors"]
    else:
        vehicles = {str(item.get("id")): item for item in definition["objects"]
                    if str(item.get("type", "")).startswith("vehicle.")}
        if role not in vehicles:
            raise CarlaImportError(f"{path} defines no vehicle {role!r} (vehicles: "
                                   f"{', '.join(sorted(vehicles)) or 'none'})")
        vehicle = vehicles[role]
        try:
            listed = [item for key in ("sensors", "objects") for item in _listed(vehicle.get(key, []), key)]
        except TypeError as error:
            raise CarlaImportError(f"{path}: the sensors of vehicle {role!r}: {error}") from None
    return {str(item.get("id")): item for item in listed}


def _pose(item: dict[str, Any]) -> dict[str, Any]:
    """A sensor's pose: its `spawn_point`, or x, y, z, roll, pitch, yaw among its attributes (carla_ego_vehicle)."""
    if "spawn_point" in item:
        return item["spawn_point"]
    return {key: item[key] for key in ("x", "y", "z", "roll", "pitch", "yaw") if key in item}


def front_camera(path: Path, role: str, sensor: str, sensors: dict[str, dict[str, Any]] | None = None) -> FrontCamera:
    """Camera `sensor` of vehicle `role` in definition file `path` (`sensors`: its vehicle_sensors, when read
    already); CarlaImportError if it is not there or does not look ahead (yaw and roll 0)."""
    sensors = vehicle_sensors(path, role) if sensors is None else sensors
    if sensor not in sensors:
        cameras = sorted(name for name, item in sensors.items()
                         if str(item.get("type", "")).startswith("sensor.camera"))
        raise CarlaImportError(f"{path}: vehicle {role!r} has no sensor {sensor!r} (cameras: "
                               f"{', '.join(cameras) or 'none'})")
    item = sensors[sensor]
    try:
        pose = _pose(item)
        if float(pose.get("yaw", 0.0)) != 0.0 or float(pose.get("roll", 0.0)) != 0.0:
            raise ValueError(f"yaw {pose.get('yaw')} and roll {pose.get('roll')}: the front camera looks straight "
                             "ahead (yaw 0, roll 0)")
        return FrontCamera(width=int(item["image_size_x"]), height=int(item["image_size_y"]),
                           fov_deg=float(item.get("fov", 90.0)),  # CARLA cameras default to 90
                           forward_m=float(pose["x"]), right_m=float(pose["y"]), up_m=float(pose["z"]),
                           pitch_deg=float(pose.get("pitch", 0.0)))
    except (KeyError, TypeError, ValueError) as error:
        raise CarlaImportError(f"{path}: camera {sensor!r} of {role!r} is not a front camera: {error}") from None
