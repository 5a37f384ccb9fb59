import numpy as np

from msfsu_common.road_option import RoadOption
import pytest

from msfsu_perception.balancing import balance_lane_follow, repeat_focus

LF, LEFT = RoadOption.LANE_FOLLOW, RoadOption.LEFT
SMALL, SHARP = 4.0 / 70, 20.0 / 70  # 4 and 20 degrees


def _labels(groups):
    """groups: (count, steer, speed, command) -> concatenated label arrays."""
    steer = np.concatenate([np.full(n, s, np.float32) for n, s, _, _ in groups])
    speed = np.concatenate([np.full(n, v, np.float32) for n, _, v, _ in groups])
    command = np.concatenate([np.full(n, c, np.uint8) for n, _, _, c in groups])
    return steer, speed, command


def test_exact_counts_of_the_papers_recipe():
    steer, speed, command = _labels([
        (100, SMALL, 8.0, LF),  # 80 discarded -> 20
        (20, SHARP, 8.0, LF),  # 1 + 6 copies -> 140
        (5, -SHARP, 0.5, LF),  # 7 copies, slow -> 7 * (1 + 3) = 140
        (7, SMALL, 0.0, LEFT),  # other commands untouched -> 7
    ])
    rows = balance_lane_follow(steer, speed, command, np.random.default_rng(0))
    counts = np.bincount(rows, minlength=len(steer))
    assert len(rows) == 20 + 140 + 140 + 7 == 307
    assert np.count_nonzero(counts[:100]) == 20 and set(counts[:100]) == {0, 1}
    assert set(counts[100:120]) == {7}
    assert set(counts[120:125]) == {28}
    assert set(counts[125:]) == {1}


def test_slow_small_steer_samples_are_kept_at_20_percent_then_quadrupled():
    steer, speed, command = _labels([(50, 0.0, 0.2, LF), (50, 0.01, 9.0, LF)])
    rows = balance_lane_follow(steer, speed, command, np.random.default_rng(3))
    counts = np.bincount(rows, minlength=100)
    kept = np.flatnonzero(counts)
    assert len(kept) == 20  # 80 % of the 100 small-steer samples discarded
    assert all(counts[row] == (4 if row < 50 else 1) for row in kept)


def test_the_5_degree_boundary_is_a_sharp_turn():
    steer, speed, command = _labels([(1, 5.0 / 70 + 1e-6, 8.0, LF), (1, 4.99 / 70, 8.0, LF)])
    rows = balance_lane_follow(steer, speed, command, np.random.default_rng(0))
    assert list(rows) == [0] * 7  # the 4.99 deg sample: round(0.8 * 1) = 1 discarded


def test_seed_fixes_which_samples_survive():
    steer, speed, command = _labels([(200, 0.0, 5.0, LF)])
    first = balance_lane_follow(steer, speed, command, np.random.default_rng(7))
    again = balance_lane_follow(steer, speed, command, np.random.default_rng(7))
    other = balance_lane_follow(steer, speed, command, np.random.default_rng(8))
    assert np.array_equal(first, again) and not np.array_equal(first, other)


def test_focus_frames_get_extra_copies_of_every_entry_and_none_with_zero():
    rows = np.array([0, 2, 2, 3, 5])  # balanced rows: row 2 already twice
    focus = np.array([False, False, True, False, False, True])
    np.testing.assert_array_equal(repeat_focus(rows, focus, 0), rows)
    np.testing.assert_array_equal(repeat_focus(rows, focus, 2), [0, 2, 2, 2, 2, 2, 2, 3, 5, 5, 5])
    with pytest.raises(ValueError):
        repeat_focus(rows, focus, -1)
