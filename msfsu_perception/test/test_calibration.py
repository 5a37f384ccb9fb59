"""Calibration frames are balanced over the navigation commands and spread over the recording."""

import numpy as np
import pytest

from msfsu_perception.calibration import command_quotas, stratified_rows


@pytest.mark.parametrize(("available", "frames", "quotas"), [
    ({1: 100, 2: 100, 3: 100, 4: 100}, 40, {1: 10, 2: 10, 3: 10, 4: 10}),
    ({1: 3, 2: 5, 3: 100, 4: 1000}, 40, {1: 3, 2: 5, 3: 16, 4: 16}),  # rare turns: the rest goes to the others
    ({1: 0, 2: 7, 3: 2, 4: 1000}, 30, {1: 0, 2: 7, 3: 2, 4: 21}),
    ({1: 2, 2: 2, 3: 2, 4: 2}, 30, {1: 2, 2: 2, 3: 2, 4: 2}),  # fewer frames than asked: all of them
    ({1: 10, 2: 10, 3: 10, 4: 10}, 6, {1: 2, 2: 2, 3: 1, 4: 1}),
])
def test_each_command_gets_an_equal_share_of_what_it_can_give(available, frames, quotas):
    assert command_quotas(available, frames) == quotas
    assert sum(quotas.values()) == min(frames, sum(available.values()))


def test_junction_frames_are_not_drowned_by_lane_following():
    commands = np.full(1000, 4, np.uint8)  # LANE_FOLLOW, with two short junction crossings
    commands[100:120], commands[600:610] = 1, 2  # LEFT, RIGHT
    rows = np.arange(1000) * 2  # cache rows of the valid frames
    chosen = stratified_rows(rows, commands, 40)
    picked = commands[chosen // 2]
    assert len(chosen) == 40 and np.all(np.diff(chosen) > 0)
    assert (np.sum(picked == 1), np.sum(picked == 2), np.sum(picked == 4)) == (16, 10, 14)  # RIGHT has only 10
    lane_follow = chosen[picked == 4]
    assert lane_follow[0] == 0 and lane_follow[-1] == 1998  # spread over the whole recording


def test_no_frames_is_an_error():
    with pytest.raises(ValueError, match="no usable frames"):
        stratified_rows(np.array([], np.int64), np.array([], np.uint8), 10)
