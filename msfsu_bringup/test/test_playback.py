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


def test_a_pause_stops_the_bags_time_and_the_rest_is_due_as_much_later_as_it_lasted():
    schedule = PlaybackSchedule(bag_start_ns=100 * S, wall_start_ns=0, rate=2.0)
    schedule.pause(wall_ns=1 * S)  # 2 s into the bag
    schedule.pause(wall_ns=2 * S)  # already paused: stays paused from 1 s
    assert schedule.paused and schedule.due_ns(102 * S) == float("inf")
    assert schedule.bag_time_ns(9 * S) == 102 * S
    schedule.set_rate(1.0, wall_ns=4 * S)  # a new rate while paused: from where it stopped, still paused
    assert schedule.paused and schedule.bag_time_ns(5 * S) == 102 * S
    schedule.resume(wall_ns=6 * S)
    assert not schedule.paused
    assert schedule.due_ns(102 * S) == 6 * S and schedule.due_ns(105 * S) == 9 * S  # nothing skipped
    schedule.resume(wall_ns=7 * S)  # not paused: nothing changes
    assert schedule.due_ns(105 * S) == 9 * S
