"""Message classes from their type names, as bags and the ROS graph spell them."""

from __future__ import annotations

import importlib


def message_class(type_name: str) -> type:
    """'sensor_msgs/msg/Image' -> sensor_msgs.msg.Image (the package must be installed)."""
    package, kind, name = type_name.split("/")
    try:
        return getattr(importlib.import_module(f"{package}.{kind}"), name)
    except (ImportError, AttributeError) as error:
        raise LookupError(f"message type {type_name} is not installed: {error}") from error
