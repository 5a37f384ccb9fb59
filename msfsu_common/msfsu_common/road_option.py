"""Navigation commands, numbered like CARLA's RoadOption (and msfsu_interfaces/NavigationCommand)."""

from __future__ import annotations

from enum import IntEnum

import numpy as np


class RoadOption(IntEnum):
    LEFT = 1
    RIGHT = 2
    STRAIGHT = 3
    LANE_FOLLOW = 4

    @property
    def branch_index(self) -> int:
        """Index of the policy branch that serves this command (branches follow the enum order)."""
        return self.value - 1


_BRANCH_INDEX = np.zeros(max(RoadOption) + 1, np.int64)
_BRANCH_INDEX[[option.value for option in RoadOption]] = [option.branch_index for option in RoadOption]


def branch_indices(values: np.ndarray) -> np.ndarray:
    """RoadOption values (e.g. a frame cache's uint8 commands) -> int64 branch indices of the network."""
    return _BRANCH_INDEX[values]


def parse_road_option(value: int) -> RoadOption:
    """Return the RoadOption for a raw message value; ValueError names the accepted values."""
    try:
        return RoadOption(int(value))
    except ValueError:
        accepted = ", ".join(f"{option.value}={option.name}" for option in RoadOption)
        raise ValueError(f"unknown navigation command {value} (accepted: {accepted})") from None
