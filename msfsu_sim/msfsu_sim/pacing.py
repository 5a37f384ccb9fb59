"""Free-running simulation, as CARLA's asynchronous mode: the simulator does not wait for the driver.

Simulated time advances at a stated real-time factor: step k of an episode is due `k * STEP_S / factor` wall
seconds after its first frame, whatever the driver did, and the control that arrived last applies (an older
frame's, when the graph was slower than the period, or none yet). The simulator's own step (render, physics)
counts against the period: a step that starts after it was due is late, and the factor achieved, simulated
over wall time, is what the episode reports beside the stated one. A late step does not start a catch-up burst
(steps back to back would leave the driver no time at all): the schedule goes on from it. ROS-free (the sim_bridge node and the
closed-loop benchmark pace with it).
"""

from __future__ import annotations

import time
from collections import Counter
from collections.abc import Callable

from msfsu_sim.environment import STEP_S


class RealTimePacer:
    def __init__(self, factor: float, step_s: float = STEP_S, clock: Callable[[], float] = time.monotonic) -> None:
        if not factor > 0:
            raise ValueError(f"the real-time factor must be positive, got {factor}")
        self.factor, self.step_s, self.clock = factor, step_s, clock
        self.period_s = step_s / factor
        self.start()

    def start(self) -> None:
        """The episode's first frame is out now."""
        self.started = self._anchor = self.clock()  # the episode's start; the schedule's (moved by late steps)
        self.steps = 0
        self.late_steps = 0
        self.control_ages: Counter[int] = Counter()  # steps between a frame and the control applied to it: count
        self.without_control = 0  # steps taken before any control arrived (the car holds still)

    def due(self) -> float:
        """Wall time at which the next step is due."""
        return self._anchor + (self.steps + 1) * self.period_s

    def late(self) -> bool:
        """The next step is already overdue (ask before waiting for it)."""
        return self.clock() > self.due()

    def step_taken(self, late: bool, control_age_s: float | None) -> None:
        """Count the step just due; `control_age_s`: frame time minus the applied control's stamp (None: none yet)."""
        if late:  # the schedule goes on from now
            self._anchor += self.clock() - self.due()
        self.steps += 1
        self.late_steps += late
        if control_age_s is None:
            self.without_control += 1
        else:
            self.control_ages[round(control_age_s / self.step_s)] += 1

    def achieved_factor(self) -> float:
        return self.steps * self.step_s / max(self.clock() - self.started, 1e-9)

    def record(self) -> dict:
        """The episode's free-running figures (JSON); control ages in steps (0: the control answers that frame)."""
        return {
            "real_time_factor": self.factor, "achieved_real_time_factor": round(self.achieved_factor(), 3),
            "steps": self.steps, "late_steps": self.late_steps, "steps_without_control": self.without_control,
            "control_age_steps": {str(age): count for age, count in sorted(self.control_ages.items())},
        }
