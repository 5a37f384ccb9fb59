"""Episode rules on scripted episodes and the trajectory RMSE on hand-made trajectories."""

import math
from dataclasses import replace

import numpy as np
import pytest

from msfsu_evaluation.closed_loop.rules import EpisodeJudge, EpisodeRules, StepState, timeout_s
from msfsu_evaluation.closed_loop.trajectory import episode_path_rmse, episode_rmse, task_rmse

ROUTE_M = 100.0


def play(states: list[StepState], **rules) -> tuple[int, object]:
    """Feed steps until the judge ends the episode: (index of the ending step, outcome)."""
    judge = EpisodeJudge(EpisodeRules(ROUTE_M, timeout_s(ROUTE_M, 5.0, 10.0), **rules))
    for index, state in enumerate(states):
        outcome = judge.update(state)
        if outcome is not None:
            return index, outcome
    return len(states), None


def driving(speed: float, steps: int, **last) -> list[StepState]:
    """A car at constant speed along the route (10 Hz); `last` overrides fields of the final step."""
    states = [StepState(t * 0.1, ROUTE_M - speed * t * 0.1, speed * t * 0.1) for t in range(steps)]
    states[-1] = StepState(**{**states[-1].__dict__, **last})
    return states


def test_timeouts_are_the_original_benchmarks():
    """CARLA's CoRL2017 suite: route at 10 km/h + 10 s; NoCrash: at 5 km/h + 20 s."""
    from msfsu_evaluation.closed_loop.suites import TASKS

    corl, nocrash = TASKS["navigation"], TASKS["nocrash_dense"]
    assert timeout_s(1000.0, corl.timeout_speed_kmh, corl.timeout_margin_s) == pytest.approx(360.0 + 10.0)
    assert timeout_s(1000.0, nocrash.timeout_speed_kmh, nocrash.timeout_margin_s) == pytest.approx(720.0 + 20.0)
    assert timeout_s(ROUTE_M, 5.0, 10.0) == pytest.approx(82.0)


def test_success_within_goal_distance():
    index, outcome = play(driving(5.0, 400))
    assert outcome.status == "success" and outcome.success
    assert index == 190  # 100 m - 5 m/s * 19.0 s = 5 m: the goal distance
    assert outcome.route_completion == 1.0


def test_simulator_arrival_is_a_success_even_outside_the_goal_distance():
    _, outcome = play(driving(5.0, 50, arrived=True))
    assert outcome.success and outcome.time_s == pytest.approx(4.9)


def test_collision_fails_with_its_type_and_completion():
    _, outcome = play(driving(5.0, 101, collision_type="pedestrian"))
    assert (outcome.status, outcome.collision_type, outcome.success) == ("collision", "pedestrian", False)
    assert outcome.route_completion == pytest.approx(0.5)


def test_collision_at_the_goal_still_fails():
    _, outcome = play(driving(5.0, 191, collision_type="vehicle"))  # the step that reaches the goal
    assert outcome.status == "collision"


def test_striking_the_kerb_or_a_building_fails_as_a_static_collision():
    """Routes v3: MetaDrive reports kerb and building strikes without ending the episode; the rules end it."""
    for kind in ("sidewalk", "building"):
        index, outcome = play(driving(5.0, 40, static_collision=kind))
        assert index == 39 and outcome.status == "collision" and outcome.collision_type == kind
    from msfsu_evaluation.closed_loop.statistics import driving_score

    assert driving_score(0.5, "sidewalk") == pytest.approx(0.5 * 0.65)  # the leaderboard's static-object penalty


def test_solid_line_crossings_are_counted_once_per_touch_and_do_not_end_the_episode():
    states = driving(10.0, 120)
    touching = {5, 6, 7, 30, 50, 51}  # three separate touches
    states = [StepState(**{**state.__dict__, "solid_line": index in touching}) for index, state in enumerate(states)]
    index, outcome = play(states)
    assert outcome.status == "success" and outcome.solid_line_crossings == 3


def test_off_road_fails():
    _, outcome = play(driving(5.0, 30, out_of_road=True))
    assert outcome.status == "off_road"


def test_slow_car_times_out():
    index, outcome = play(driving(1.0, 2000), blocked_s=1000.0)
    assert outcome.status == "timeout" and index == 820 and outcome.route_completion == pytest.approx(0.82)


def test_standing_car_is_blocked_after_blocked_s_of_no_progress():
    moving = driving(5.0, 50)  # 4.9 s, 24.5 m
    standing = [StepState(4.9 + 0.1 * k, moving[-1].distance_to_goal_m, moving[-1].route_progress_m)
                for k in range(1, 400)]
    index, outcome = play(moving + standing, blocked_s=20.0)
    assert outcome.status == "blocked"
    assert outcome.time_s == pytest.approx(4.8 + 20.0)  # progress last counted at 4.8 s (the 1 m step)


def test_waiting_for_someone_does_not_count_towards_blocked():
    moving = driving(5.0, 50)
    where = (moving[-1].distance_to_goal_m, moving[-1].route_progress_m)
    waiting = [StepState(4.9 + 0.1 * k, *where, waiting_for="pedestrian") for k in range(1, 300)]  # 30 s
    standing = [StepState(34.8 + 0.1 * k, *where) for k in range(1, 400)]
    index, outcome = play(moving + waiting + standing, blocked_s=20.0)
    assert outcome.status == "blocked"
    assert outcome.time_s == pytest.approx(34.8 + 19.9)  # 0.1 s idle before the wait, 19.9 s after it
    _, outcome = play(moving + [StepState(4.9 + 0.1 * k, *where, waiting_for="vehicle") for k in range(1, 2000)],
                      blocked_s=20.0)
    assert outcome.status == "timeout"  # a wait that never ends is a timeout, not `blocked`


def test_creeping_below_the_progress_threshold_is_blocked():
    creeping = [StepState(0.1 * k, ROUTE_M, 0.004 * k) for k in range(300)]  # 4 cm/s
    _, outcome = play(creeping, blocked_s=5.0)
    assert outcome.status == "blocked"


def test_rmse_is_the_paper_formula_on_a_known_offset():
    expert = np.stack([np.arange(10.0), np.zeros(10)], axis=1)
    agent = expert + [0.0, 0.3]  # 0.3 m to the left all the way
    assert episode_rmse(agent, expert) == pytest.approx(0.3)
    assert episode_path_rmse(agent, expert) == pytest.approx(0.3)


def test_rmse_pairs_timesteps_and_holds_the_expert_at_its_end():
    expert = np.array([[0.0, 0.0], [1.0, 0.0]])
    agent = np.array([[0.0, 0.0], [0.0, 0.0], [1.0, 3.0]])  # lags, then ends 3 m off the expert's end
    assert episode_rmse(agent, expert) == pytest.approx(math.sqrt((0 + 1 + 9) / 3))
    # along the same path a lag costs nothing in the path variant
    assert episode_path_rmse(agent[:2], expert) == 0.0


def test_the_path_rmse_is_the_nearest_segment_of_every_segment_to_the_bit():
    """Measured block by block against the segments that can be nearest, it equals the distance to every segment."""
    rng = np.random.default_rng(7)
    for steps in (1, 2, 17, 300):
        heading = np.cumsum(rng.normal(0.0, 0.3, steps))
        expert = np.cumsum(np.stack([np.cos(heading), np.sin(heading)], axis=1), axis=0)
        for agent in (expert[::2] + rng.normal(0.0, 0.5, expert[::2].shape),  # close, lagging
                      expert[::-1] + [40.0, -25.0],  # far off, backwards
                      np.repeat(expert[:1], 5, axis=0)):  # standing at the start
            starts, vectors = expert[:-1], np.diff(expert, axis=0)
            if len(vectors) == 0:
                assert episode_path_rmse(agent, expert) == episode_rmse(agent, expert)
                continue
            lengths_sq = np.maximum(np.einsum("ij,ij->i", vectors, vectors), 1e-12)
            offsets = agent[:, None, :] - starts[None, :, :]
            t = np.clip(np.einsum("tsk,sk->ts", offsets, vectors) / lengths_sq, 0.0, 1.0)
            nearest = starts[None] + t[..., None] * vectors[None]
            every_segment = float(np.sqrt(np.sum((agent[:, None, :] - nearest) ** 2, axis=2).min(axis=1).mean()))
            assert episode_path_rmse(agent, expert) == every_segment


def test_task_rmse_averages_episodes_and_is_none_without_successes():
    assert task_rmse([0.1, 0.3]) == pytest.approx(0.2)
    assert task_rmse([]) is None


def test_rmse_rejects_empty_trajectories():
    with pytest.raises(ValueError, match="non-empty"):
        episode_rmse(np.zeros((0, 2)), np.zeros((3, 2)))


def test_a_crossing_is_placed_in_the_junction_on_its_approach_or_on_lane_follow():
    from msfsu_evaluation.closed_loop.lateral import place_on_route

    spans, lookahead = [(100.0, 130.0), (300.0, 320.0)], 15.0
    assert [place_on_route(p, spans, lookahead) for p in (0.0, 84.9, 85.0, 99.9, 100.0, 129.9, 130.0, 290.0, 310.0)] == [
        "lane_follow", "lane_follow", "junction_approach", "junction_approach", "junction", "junction", "lane_follow",
        "junction_approach", "junction"]
    assert place_on_route(50.0, [], lookahead) == "lane_follow"  # a route without a junction


def test_solid_line_rates_pool_crossings_over_the_metres_driven_under_each_command_and_place():
    from msfsu_evaluation.closed_loop.episode_record import EpisodeResult, SolidLineCrossing
    from msfsu_evaluation.closed_loop.lateral import solid_line_markdown, solid_line_summary

    older = EpisodeResult("a", "r3", "success", True, time_s=30.0, steps=300, route_completion=1.0, collision_type="",
                          distance_to_goal_m=0.0, timeout_s=60.0, wall_s=10.0, unanswered_frames=0,
                          solid_line_crossings=4)  # a record before the places were kept: left out

    def episode(route: str, crossings: list[tuple[str, str]], by_command: dict, by_place: dict) -> EpisodeResult:
        return replace(older, route=route, solid_line_crossings=len(crossings),
                       solid_lines=tuple(SolidLineCrossing(1.0, 10.0, c, w) for c, w in crossings),
                       metres_by_command=by_command, metres_by_place=by_place)

    episodes = [
        episode("r1", [("LEFT", "junction_approach"), ("LEFT", "junction")], {"LANE_FOLLOW": 900.0, "LEFT": 100.0},
                {"lane_follow": 880.0, "junction_approach": 80.0, "junction": 40.0}),
        episode("r2", [("LANE_FOLLOW", "lane_follow")], {"LANE_FOLLOW": 1100.0, "LEFT": 150.0},
                {"lane_follow": 1100.0, "junction_approach": 120.0, "junction": 30.0}),
        older,
    ]
    summary = solid_line_summary(episodes, {"r1": "train", "r2": "train", "r3": "train"})
    cell = summary["a"]["train"]
    assert cell["episodes"] == 2
    assert cell["by_command"]["LEFT"] == {"crossings": 2, "km": 0.25, "per_km": 8.0}
    assert cell["by_command"]["LANE_FOLLOW"] == {"crossings": 1, "km": 2.0, "per_km": 0.5}
    assert cell["by_command"]["RIGHT"] == {"crossings": 0, "km": 0.0, "per_km": None}  # never driven: no rate
    assert cell["by_place"]["junction_approach"]["per_km"] == 5.0 and cell["by_place"]["junction"]["per_km"] == 14.286
    assert "| a | train | 2 | 8.00 (2 / 0.2 km) | – | – | 0.50 (1 / 2.0 km) | 0.51 (1 / 2.0 km) | 5.00 (1 / 0.2 km) | " \
           "14.29 (1 / 0.1 km) |" in solid_line_markdown(summary)
    assert solid_line_summary(episodes[2:], {"r3": "train"}) == {} and solid_line_markdown({}) == []
