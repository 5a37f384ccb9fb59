"""The free-running pacer: steps on the wall clock at a real-time factor, late steps, control ages."""

import pytest

from msfsu_sim.pacing import RealTimePacer


class FakeClock:
    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


def test_steps_are_due_at_the_factor_and_late_steps_move_the_schedule_on():
    clock = FakeClock()
    pacer = RealTimePacer(0.5, step_s=0.1, clock=clock)  # a step every 0.2 s of wall time
    assert pacer.due() == pytest.approx(100.2)
    clock.now = 100.05
    assert not pacer.late()
    clock.now = 100.2
    pacer.step_taken(False, 0.0)
    assert pacer.due() == pytest.approx(100.4)
    clock.now = 100.7  # the simulator took 0.5 s for this step: late by 0.3 s
    assert pacer.late()
    pacer.step_taken(True, 0.1)
    assert pacer.due() == pytest.approx(100.9)  # 0.2 s from now, no catch-up burst
    clock.now = 100.9
    pacer.step_taken(False, None)
    record = pacer.record()
    assert record["steps"] == 3 and record["late_steps"] == 1 and record["steps_without_control"] == 1
    assert record["control_age_steps"] == {"0": 1, "1": 1}
    assert record["achieved_real_time_factor"] == pytest.approx(0.3 / 0.9, abs=1e-3)
    assert record["real_time_factor"] == 0.5


def test_a_new_episode_starts_a_new_schedule_and_the_factor_must_be_positive():
    clock = FakeClock()
    pacer = RealTimePacer(1.0, clock=clock)
    pacer.step_taken(True, 0.0)
    clock.now = 200.0
    pacer.start()
    assert pacer.due() == pytest.approx(200.1) and pacer.record()["steps"] == 0
    with pytest.raises(ValueError, match="positive"):
        RealTimePacer(0.0)
