"""The paper's MSFSU success rates per benchmark cell (Tables 1 and 2) and the goals the v3 models are held to.

The paper's "training scenario" is our condition "train" and its "testing scenario" (a new town and new weathers)
is our "heldout". The paper drove 25 routes per cell, as routes v3 do.
GOALS are the targets of the v3 models (issue 58, which keeps issue 29's). The static CoRL2017 cells get 96 % rather than the paper's 100 %:
24 of 25 routes, so one failure is allowed. navigation_dynamic gets 90 % in both conditions. NoCrash regular and
dense get the paper's own rates. NoCrash empty has no goal, only the paper's rate.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

Cell = tuple[str, str, str]  # (suite, task key of suites.TASKS, condition)

# Table 1 (CoRL2017) and Table 2 (NoCrash; its "±" spreads over the paper's repeated runs are left out), MSFSU
# column, success rate in %.
PAPER_MSFSU_SUCCESS: Mapping[Cell, float] = {
    ("corl2017", "straight", "train"): 100, ("corl2017", "straight", "heldout"): 100,
    ("corl2017", "one_turn", "train"): 100, ("corl2017", "one_turn", "heldout"): 100,
    ("corl2017", "navigation", "train"): 100, ("corl2017", "navigation", "heldout"): 100,
    ("corl2017", "navigation_dynamic", "train"): 98, ("corl2017", "navigation_dynamic", "heldout"): 94,
    ("nocrash", "nocrash_empty", "train"): 100, ("nocrash", "nocrash_empty", "heldout"): 100,
    ("nocrash", "nocrash_regular", "train"): 91, ("nocrash", "nocrash_regular", "heldout"): 82,
    ("nocrash", "nocrash_dense", "train"): 61, ("nocrash", "nocrash_dense", "heldout"): 43,
}
GOALS: Mapping[Cell, float] = {
    **{("corl2017", task, condition): 96 for task in ("straight", "one_turn", "navigation")
       for condition in ("train", "heldout")},
    ("corl2017", "navigation_dynamic", "train"): 90, ("corl2017", "navigation_dynamic", "heldout"): 90,
    ("nocrash", "nocrash_regular", "train"): 91, ("nocrash", "nocrash_regular", "heldout"): 82,
    ("nocrash", "nocrash_dense", "train"): 61, ("nocrash", "nocrash_dense", "heldout"): 43,
}
# Pedestrian collisions per km over every held-out cell: at most this (issue 58).
PEDESTRIAN_PER_KM_HELDOUT_GOAL = 0.2


@dataclass(frozen=True)
class Against:
    """One cell of one agent measured against the paper and the goal."""

    rate: float  # successes / episodes, %
    low: float  # Wilson 95 % interval, %
    high: float
    paper: float | None
    goal: float | None

    @property
    def versus_paper(self) -> str:
        """The paper's rate against ours: "at or above", "below, interval holds it" (these routes cannot tell), or
        "below" (our interval excludes it)."""
        if self.paper is None:
            return "–"
        if self.rate >= self.paper:
            return "at or above"
        return "below, interval holds it" if self.high >= self.paper else "below"

    @property
    def goal_met(self) -> bool | None:
        return None if self.goal is None else self.rate >= self.goal


def against(cell: Cell, successes: int, episodes: int, low: float, high: float) -> Against:
    """`successes`/`episodes` with its interval (fractions) in `cell`, measured against the paper and the goal."""
    return Against(100 * successes / episodes, 100 * low, 100 * high, PAPER_MSFSU_SUCCESS.get(cell), GOALS.get(cell))
