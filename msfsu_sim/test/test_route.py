import math

from msfsu_common.road_option import RoadOption
from msfsu_control.path_options import turn_option
from msfsu_sim.route import is_junction_edge


def test_turn_option_thresholds():
    assert turn_option(math.radians(90)) is RoadOption.LEFT
    assert turn_option(math.radians(-90)) is RoadOption.RIGHT
    assert turn_option(math.radians(5)) is RoadOption.STRAIGHT


def test_junction_edge_is_the_edge_entering_an_intersection_block():
    assert is_junction_edge("1S0_0_", "2X0_0_")
    assert is_junction_edge("-3C0_1_", "4T1_0_")
    assert not is_junction_edge("2X0_0_", "2X0_1_")  # exit road inside the block
    assert not is_junction_edge("2X0_1_", "3C0_0_")  # curve
    assert not is_junction_edge(">>>", "1S0_0_")


def test_junction_edge_entered_back_along_an_exit_road():
    assert is_junction_edge("-2X1_0_", "2X2_0_")  # from one exit road to another
    assert is_junction_edge("-4T2_0_", "-3C0_1_")  # back to the previous block
    assert not is_junction_edge("-2X0_1_", "-2X0_0_")  # driving in along the exit road
    assert not is_junction_edge("-3C0_1_", "-3C0_0_")
    assert not is_junction_edge("-3C0_0_", "-2X2_1_")  # the next block's road onto the exit road
