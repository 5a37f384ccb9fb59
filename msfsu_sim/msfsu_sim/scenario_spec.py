"""What a per-ability scenario is (ROS-free, no simulator): its kind, its conflict, its goal, its actor's parameters.

The simulator side (placing and moving the actor) is msfsu_sim.scripted; the suite of scenarios is
msfsu_evaluation.closed_loop.abilities. This module imports neither MetaDrive nor numpy, so route files and reports
read scenarios without starting the simulator.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, fields

PEDESTRIAN_CROSSING = "pedestrian_crossing"
PEDESTRIAN_BEHIND_PARKED_CAR = "pedestrian_behind_parked_car"
LEAD_BRAKING = "lead_braking"
CUT_IN = "cut_in"
CROSSING_TRAFFIC = "crossing_traffic"
CLEAR_ROAD = "clear_road"
KINDS = (PEDESTRIAN_CROSSING, PEDESTRIAN_BEHIND_PARKED_CAR, LEAD_BRAKING, CUT_IN, CROSSING_TRAFFIC, CLEAR_ROAD)
SIDES = ("left", "right", "")

@dataclass(frozen=True)
class ScenarioSpec:
    """One scenario: its kind, where the conflict is, where the ego's goal is, and its actor's parameters.

    Fields a kind does not use keep their defaults. Arc lengths along the ego's route (RouteTracker's), metres.
    """

    kind: str  # one of KINDS
    conflict_m: float  # the route arc length where ego and actor meet
    goal_m: float  # the route arc length that ends the episode as a success
    initial_speed_mps: float  # the ego's speed at the first step
    side: str = ""  # pedestrian_crossing: the kerb it starts from; crossing_traffic: the side it comes from
    actor_speed_mps: float = 0.0  # walking / driving speed of the actor
    timing_s: float = 0.0  # added to the actor's time to the conflict point when it is cued (see module doc)
    gap_m: float = 0.0  # lead_braking: start gap (bumper to bumper); cut_in: gap ahead of the ego when it moves over
    decel_mps2: float = 0.0  # lead_braking, cut_in: how hard it brakes
    slow_speed_mps: float = 0.0  # cut_in: the speed it brakes to
    hold_s: float = 0.0  # lead_braking, cut_in: how long it keeps that speed
    vehicle: str = ""  # the actor car's MetaDrive class (vehicle_type), "" for pedestrians
    actor_lanes: tuple[tuple[str, str], ...] = ()  # crossing_traffic: the roads of its path (its lane 0 of each)

    def __post_init__(self) -> None:
        if self.kind not in KINDS:
            raise ValueError(f"unknown scenario kind {self.kind!r} (one of {', '.join(KINDS)})")
        if self.side not in SIDES:
            raise ValueError(f"scenario side must be left, right or empty, got {self.side!r}")
        if not self.goal_m > self.conflict_m:
            raise ValueError(f"the goal ({self.goal_m} m) must lie beyond the conflict ({self.conflict_m} m)")

    @classmethod
    def from_dict(cls, data: dict) -> ScenarioSpec:
        known = {field.name for field in fields(cls)}
        unknown = set(data) - known
        if unknown:
            raise ValueError(f"unknown scenario fields {sorted(unknown)}")
        values = dict(data)
        values["actor_lanes"] = tuple(tuple(road) for road in values.get("actor_lanes", ()))
        return cls(**values)

    def to_dict(self) -> dict:
        return {key: value for key, value in asdict(self).items() if value not in ("", 0.0, ())
                or key in ("kind", "conflict_m", "goal_m", "initial_speed_mps")}
