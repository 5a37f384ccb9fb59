"""A run's speed from its episode records: steps/s per worker, the per-step stage and CPU milliseconds, the end line."""

import json

import pytest

from msfsu_evaluation.closed_loop.episode_record import EpisodeResult, EpisodeTiming
from msfsu_evaluation.closed_loop.throughput import by_agent, summary_line, throughput


def episode(agent: str, steps: int, wall_s: float, timing: EpisodeTiming | None) -> EpisodeResult:
    return EpisodeResult(agent, "nocrash/nocrash_empty/train/00", "success", True, steps / 10, steps, 1.0, "", 0.0,
                         60.0, wall_s, 0, timing=timing)


def test_the_rate_is_steps_over_worker_seconds_and_stages_are_per_step_over_the_timed_episodes_only():
    timed = episode("msfsu", 100, 5.0, EpisodeTiming({"reset": 1.0, "simulate": 3.0, "wait for control": 1.0},
                                                      {"worker": 4.0, "perception": 1.0}))
    other = episode("msfsu", 300, 15.0, EpisodeTiming({"simulate": 9.0, "publish": 6.0}, {"worker": 12.0}))
    untimed = episode("msfsu", 100, 10.0, None)  # recorded before timing was kept: counts in the rate only
    speed = throughput([timed, other, untimed])
    assert (speed.episodes, speed.steps, speed.wall_s, speed.timed_steps) == (3, 500, 30.0, 400)
    assert speed.steps_per_s == pytest.approx(500 / 30)
    # loop order of episode.STAGES, whatever order the records hold them in; ms per timed step
    assert speed.stage_ms == {"reset": 2.5, "simulate": 30.0, "publish": 15.0, "wait for control": 2.5}
    assert list(speed.stage_ms) == ["reset", "simulate", "publish", "wait for control"]
    assert speed.cpu_ms == {"perception": 2.5, "worker": 40.0}
    assert json.loads(json.dumps(speed.to_dict()))["steps_per_s_per_worker"] == 16.67


def test_a_record_with_timing_reads_back_as_it_was_written():
    record = episode("msfsu", 10, 1.0, EpisodeTiming({"simulate": 0.5}, {"worker": 0.4}))
    line = json.dumps(record.to_dict())
    assert json.loads(line)["timing"] == {"wall_s": {"simulate": 0.5}, "cpu_s": {"worker": 0.4}}
    assert EpisodeResult.from_dict(json.loads(line)) == record


def test_the_end_line_gives_each_agent_and_the_episodes_per_hour_of_the_leg():
    episodes = [episode("msfsu", 100, 5.0, None), episode("expert", 400, 4.0, None), episode("msfsu", 100, 5.0, None)]
    assert list(by_agent(episodes)) == ["expert", "msfsu"]
    line = summary_line(by_agent(episodes), leg_wall_s=36.0, workers=2)
    assert line == ("throughput: expert 100.0 steps/s per worker (400 steps, 1 episodes); msfsu 20.0 steps/s per "
                    "worker (200 steps, 2 episodes); 300 episodes/h with 2 workers")
    assert summary_line(by_agent([]), 10.0, 2) == "throughput: no episode finished"
