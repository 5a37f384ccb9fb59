"""Navigation commands, numbered like CARLA's RoadOption (and msfsu_interfaces/NavigationCommand)."""

from __future__ import annotations

from enum import IntEnum


class RoadOption(IntEnum):
    LEFT = 1
    RIGHT = 2
    STRAIGHT = 3
    LANE_FOLLOW = 4

    @property
    def branch_index(self) -> int:
        """Index of the policy branch that serves this command (branches follow the enum order)."""
        return self.value - 1


def parse_road_option(value: int) -> RoadOption:
    """Return the RoadOption for a raw message value; ValueError names the accepted values."""
    try:
        return RoadOption(int(value))
    except ValueError:
        accepted = ", ".join(f"{option.value}={option.name}" for option in RoadOption)
        raise ValueError(f"unknown navigation command {value} (accepted: {accepted})") from None
