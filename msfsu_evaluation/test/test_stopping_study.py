"""The stopping study's measures on hand-made numbers: each can come out either way."""

import numpy as np
import pytest

from msfsu_evaluation.stopping_study import BANDS_M, bootstrap_ratio, creep, stop_targets


def test_a_network_that_stops_where_the_expert_stops_keeps_nothing_moving():
    expert = np.array([0.0, 0.0, 0.2, 5.0, 8.0])
    stopping = stop_targets(np.array([0.0, 0.1, 0.3, 5.0, 8.0]), expert, "good")
    assert (stopping.stop_frames, stopping.above_stop_share, stopping.creep_frames) == (3, 0.0, 0)
    creeping = stop_targets(np.array([0.7, 0.8, 0.7, 5.0, 8.0]), expert, "creep")
    assert creeping.above_stop_share == 1.0 and creeping.target_median == pytest.approx(0.7)


def test_a_creep_between_stop_and_drive_labels_is_told_from_one_the_expert_asked_for():
    network = np.full(8, 0.8)
    two_modes = stop_targets(network, np.array([0.0, 0.0, 0.0, 0.0, 6.0, 7.0, 8.0, 8.0]), "mean of two modes")
    assert (two_modes.creep_expert_stop_share, two_modes.creep_expert_drive_share,
            two_modes.creep_expert_between_share) == (0.5, 0.5, 0.0)
    asked = stop_targets(network, np.full(8, 0.9), "the expert creeps too")
    assert asked.creep_expert_between_share == 1.0
    assert stop_targets(np.array([np.nan, 0.8]), np.array([0.0, np.nan]), "no pairs").stop_frames == 0


def test_the_recall_interval_holds_the_recall_and_is_none_without_pixels():
    hits, totals = np.array([5, 0, 10, 3]), np.array([10, 10, 10, 10])
    low, high = bootstrap_ratio(hits, totals)
    assert low <= 18 / 40 <= high and high - low > 0.05
    assert bootstrap_ratio(np.zeros(3, int), np.zeros(3, int)) is None
    assert [band[0] for band in BANDS_M] == [0.0, 5.0, 10.0, 20.0]


def test_a_creep_is_slowing_down_and_moving_on_not_standing_or_never_slowing():
    time = np.arange(0.0, 10.0, 0.1)
    slowed_then_crept = np.where(time < 5.0, 5.0, 0.4)  # 0.4 m/s for 5 s: 2 m after slowing
    assert creep(time, slowed_then_crept) is True
    stood = np.where(time < 5.0, 5.0, 0.0)  # stopped and was hit standing
    assert creep(time, stood) is False
    assert creep(time, np.full_like(time, 5.0)) is False  # never slowed
    assert creep(time, np.where(time < 1.0, 0.0, 0.4)) is True  # the start from rest is not a slowing, the creep is
    assert creep(time, np.where(time < 9.5, 5.0, 0.3)) is False  # slowed in the last 0.5 s: 0.15 m
