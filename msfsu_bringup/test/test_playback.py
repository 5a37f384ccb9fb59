"""Bag playback schedule: due times at a rate, and a rate changed while playing (no ROS)."""

import pytest

from msfsu_bringup.playback import PlaybackSchedule

S = 1_000_000_000  # ns


def test_messages_are_due_at_their_bag_time_divided_by_the_rate():
    schedule = PlaybackSchedule(bag_start_ns=100 * S, wall_start_ns=7 * S, rate=2.0)
    assert [schedule.due_ns(t * S) for t in (100, 101, 110)] == [7 * S, 7.5 * S, 12 * S]


def test_a_new_rate_plays_the_rest_of_the_bag_at_it_from_the_bag_time_reached_when_it_was_set():
    schedule = PlaybackSchedule(bag_start_ns=100 * S, wall_start_ns=0, rate=1.0)
    schedule.set_rate(4.0, wall_ns=3 * S)  # 3 s into the bag
    assert schedule.bag_time_ns(3 * S) == 103 * S
    assert schedule.due_ns(103 * S) == 3 * S  # no jump at the change
    assert schedule.due_ns(111 * S) == 5 * S  # the next 8 s of bag in 2 s
    schedule.set_rate(0.5, wall_ns=5 * S)
    assert schedule.due_ns(112 * S) == 7 * S


def test_a_rate_must_be_positive():
    with pytest.raises(ValueError, match="playback rate must be positive, got 0.0"):
        PlaybackSchedule(0, 0, 0.0)
    with pytest.raises(ValueError, match="playback rate must be positive, got -1.0"):
        PlaybackSchedule(0, 0, 1.0).set_rate(-1.0, 0)
