"""The sim_bridge's live status: a line every period of sim time, episode-end lines, the run summary."""

import numpy as np

from msfsu_common.road_option import RoadOption
from msfsu_sim.environment import Observation, Odometry
from msfsu_sim.status import RunStatus


class FakeClock:
    """Wall time under the test's control (the status reports simulator frames per wall second)."""

    def __init__(self) -> None:
        self.now = 0.0

    def __call__(self) -> float:
        return self.now


def observation(step: int, speed: float = 5.0, progress: float = 0.0, **flags) -> Observation:
    empty = np.zeros((1, 1), np.uint8)
    return Observation(step=step, time_s=step * 0.1, rgb=np.zeros((1, 1, 3), np.uint8), depth=empty.astype(np.float32),
                       semantic_ids=empty, odometry=Odometry(0.0, 0.0, 0.0, speed, 0.0), command=RoadOption.LEFT,
                       route_progress_m=progress, route_completion=0.0,
                       collision=bool(flags.get("collision_type")), out_of_road=flags.get("out_of_road", False),
                       arrived=flags.get("arrived", False), collision_type=flags.get("collision_type", ""))


def test_a_status_line_every_period_of_sim_time_with_progress_speed_command_steps_and_rate():
    clock = FakeClock()
    status = RunStatus(period_s=2.0, episodes=2, clock=clock)
    status.start_episode(route_length_m=509.0)
    lines = []
    for step in range(1, 51):  # 5 s of sim time at 4 frames per wall second, every 10th step after a timeout
        clock.now += 0.25
        line = status.step(observation(step, progress=step * 0.5), lockstep=step % 10 != 0)
        if line is not None:
            lines.append((step, line))
    assert [step for step, _ in lines] == [20, 40]
    assert lines[1][1] == ("episode 0 |    4.0 s | route   20/509 m |  5.0 m/s | LEFT | "
                           "steps 36 lockstep / 4 timeout | 4.0 frames/s")
    end = status.end_episode(observation(51, progress=509.0, arrived=True))
    assert end.endswith("ended: arrived, time to goal 5.1 s") and not status.finished

    status.start_episode(route_length_m=100.0)
    clock.now += 1.0
    assert status.step(observation(1), lockstep=True) is None
    end = status.end_episode(observation(2, collision_type="pedestrian"))
    assert end.startswith("episode 1 |") and end.endswith("ended: collision (pedestrian) at 0.2 s")
    assert status.finished
    assert status.summary() == ("2 episodes: 1 arrived, 1 collision (pedestrian), mean time to goal 5.1 s; "
                                "steps 46 lockstep / 5 timeout, 3.8 frames/s overall (resets included)")


def test_no_status_lines_when_the_period_is_zero_and_no_end_when_episodes_is_zero():
    status = RunStatus(period_s=0.0, episodes=0, clock=FakeClock())
    status.start_episode(route_length_m=50.0)
    assert all(status.step(observation(step), lockstep=True) is None for step in range(1, 200))
    status.end_episode(observation(200, out_of_road=True))
    assert not status.finished and status.summary().startswith("1 episode: 1 out of road;")
