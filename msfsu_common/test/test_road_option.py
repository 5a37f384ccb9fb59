import numpy as np
import pytest

from msfsu_common.road_option import RoadOption, branch_indices, parse_road_option


def test_branch_indices_follow_each_options_branch_index():
    values = np.array([option.value for option in RoadOption] * 2, np.uint8)
    expected = [RoadOption(value).branch_index for value in values]
    assert branch_indices(values).tolist() == expected and branch_indices(values).dtype == np.int64
    assert sorted(option.branch_index for option in RoadOption) == list(range(len(RoadOption)))
    assert branch_indices(np.uint8(RoadOption.LANE_FOLLOW)) == RoadOption.LANE_FOLLOW.branch_index


def test_unknown_command_names_the_accepted_values():
    assert parse_road_option(2) is RoadOption.RIGHT
    with pytest.raises(ValueError, match="unknown navigation command 7 .*4=LANE_FOLLOW"):
        parse_road_option(7)
