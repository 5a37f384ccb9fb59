"""The pure parts of the lane diagnosis: junction phases, the path beside the route, turn-in, lead and lag, rates."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from experiments.model_v4.lane_closed_loop import Crossing, rate
from experiments.model_v4.lane_places import (Place, RouteLine, bin_means, follow, junction_place, lead_lag_steps,
                                              turn_in_m, unwrap_from)
from msfsu_common.road_option import RoadOption


def test_a_progress_is_in_a_junction_on_its_approach_after_it_or_away():
    spans = [(100.0, 130.0), (200.0, 210.0)]
    assert junction_place(90.0, spans) == Place("approach", 0, -10.0)
    assert junction_place(100.0, spans) == Place("in", 0, 0.0)
    assert junction_place(129.0, spans) == Place("in", 0, 29.0)
    assert junction_place(135.0, spans) == Place("after", 0, 35.0)
    assert junction_place(150.0, spans) == Place("away", None, None)
    assert junction_place(195.0, spans) == Place("approach", 1, -5.0)
    assert junction_place(212.0, spans) == Place("after", 1, 12.0)


def test_the_next_junctions_approach_wins_over_the_last_ones_exit():
    assert junction_place(140.0, [(100.0, 130.0), (150.0, 160.0)]) == Place("approach", 1, -10.0)


def _straight_route() -> RouteLine:
    x = np.arange(0.0, 100.0, 2.0)
    options = np.full(len(x), RoadOption.LANE_FOLLOW.value, np.uint8)
    options[(x >= 40.0) & (x < 60.0)] = RoadOption.LEFT.value
    return RouteLine(np.stack([x, np.zeros_like(x)], 1), options)


def test_a_route_knows_its_junctions_and_their_commands():
    line = _straight_route()
    assert line.spans() == [(40.0, 60.0)]
    assert line.junction_options() == [RoadOption.LEFT.value]


def test_the_path_is_measured_along_the_route_left_negative():
    line = _straight_route()
    x = np.arange(1.0, 90.0, 1.0)
    left = follow(line, np.stack([x, np.full_like(x, 1.0)], 1), np.full_like(x, 0.1))
    np.testing.assert_allclose(left.progress_m, x, atol=1e-9)
    np.testing.assert_allclose(left.offset_m, -1.0, atol=1e-9)  # 1 m left of the route
    np.testing.assert_allclose(left.heading_error_rad, 0.1, atol=1e-9)  # turned left of it
    right = follow(line, np.stack([x, np.full_like(x, -0.5)], 1), np.zeros_like(x))
    np.testing.assert_allclose(right.offset_m, 0.5, atol=1e-9)


def test_the_turn_in_is_where_the_heading_first_turned_that_far_toward_the_turn():
    into = np.arange(-15.0, 30.0, 1.0)
    change = np.radians(np.clip(into * 3.0, 0.0, 90.0))  # turning left from the junction's start
    assert turn_in_m(into, change, +1, 10.0) == 4.0  # 12 degrees there, 9 one metre before
    assert turn_in_m(into, change, -1, 10.0) is None  # never turned right
    early = np.radians(np.clip((into + 5.0) * 3.0, 0.0, 90.0))  # the same turn begun 5 m before the junction
    assert turn_in_m(into, early, +1, 10.0) == -1.0


def test_a_heading_change_is_continuous_across_pi():
    change = unwrap_from(np.array([3.1, -3.1, -3.0]), 3.0)
    np.testing.assert_allclose(change, [0.1, 2 * math.pi - 6.1, 2 * math.pi - 6.0], atol=1e-9)


def test_a_network_that_does_now_what_the_label_says_later_leads():
    t = np.arange(200)
    expert = np.sin(t / 8.0)
    assert lead_lag_steps(expert[3:], expert[:-3], 10) == 3  # network[t] = expert[t + 3]
    assert lead_lag_steps(expert[:-4], expert[4:], 10) == -4
    assert lead_lag_steps(np.zeros(50), expert[:50], 10) is None  # no spread: no answer
    assert lead_lag_steps(expert[:8], expert[:8], 10) is None  # too short for the shifts


def test_bin_means_leave_empty_bins_empty():
    assert bin_means(np.array([1.0, 3.0, 5.0]), np.array([0.5, 0.7, 2.5]), [0.0, 1.0, 2.0, 3.0]) == [2.0, None, 5.0]


def _crossing(route: str, command: str | None, phase: str) -> Crossing:
    return Crossing("net", route, "train", 1.0, command or "LANE_FOLLOW", "junction", phase, command, 0.0, 20.0, -1.0,
                    0.0, False, 0.0)


def test_a_rate_is_crossings_over_the_kilometres_driven_there():
    crossings = [_crossing("a", "LEFT", "in"), _crossing("a", "LEFT", "in"), _crossing("b", None, "away")]
    metres = {("a", "LEFT", "in"): 500.0, ("a", "-", "away"): 500.0, ("b", "-", "away"): 1000.0}
    everything = rate(crossings, metres, ["a", "b"])
    assert everything["crossings"] == 3 and everything["km"] == 2.0 and everything["per_km"] == 1.5
    left = rate(crossings, metres, ["a", "b"], lambda c: c.junction_command == "LEFT",
                lambda command, phase: command == "LEFT")
    assert left["crossings"] == 2 and left["km"] == 0.5 and left["per_km"] == 4.0
    low, high = everything["ci95"]
    assert low <= 1.5 <= high


def test_the_committed_page_is_its_record_rendered():
    import json

    from experiments.model_v4.lane_diagnosis import PAGE, RECORD, dump
    from experiments.model_v4.lane_page import render

    folder = Path(__file__).resolve().parents[3] / "docs" / "results" / "model_v4" / "lane_diagnosis"
    study = json.loads((folder / RECORD).read_text())
    assert (folder / PAGE).read_text() == render(study), (
        "stale: python -m experiments.model_v4.lane_diagnosis --render docs/results/model_v4/lane_diagnosis")
    assert dump(study) == (folder / RECORD).read_text()
    assert all((folder / figure["file"]).exists() for figure in study["figures"])


if __name__ == "__main__":
    raise SystemExit(pytest.main([__file__, "-q"]))
