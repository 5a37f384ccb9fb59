"""A report's figures: paper Fig. 7, the agents' and the expert's trajectories on one route."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

from msfsu_evaluation.closed_loop.runner import EXPERT  # noqa: E402
from msfsu_evaluation.closed_loop.runs import Records  # noqa: E402
from msfsu_evaluation.closed_loop.suites import BenchmarkRoute  # noqa: E402


def plot_trajectories(records: Records, route_key: str, agents: Sequence[str], path: Path) -> Path | None:
    """Paper Fig. 7: the agents' and the expert's trajectory on one route, and their yaw rates over time."""
    drawn = [(agent, records[(agent, route_key)].trajectory()) for agent in agents if (agent, route_key) in records]
    if not drawn:
        return None
    figure, (xy, yaw) = plt.subplots(1, 2, figsize=(11, 4.5))
    for agent, trajectory in drawn:
        style = dict(color="black", linestyle="--") if agent == EXPERT else {}
        xy.plot(trajectory[:, 1], trajectory[:, 2], label=agent, **style)
        yaw.plot(trajectory[:, 0] - trajectory[0, 0], trajectory[:, 4], label=agent, **style)
    xy.set(title=f"trajectory ({route_key})", xlabel="x (m)", ylabel="y (m)")
    xy.set_aspect("equal", adjustable="datalim")
    yaw.set(title="yaw rate", xlabel="time (s)", ylabel="yaw rate (rad/s)")
    xy.legend()
    figure.tight_layout()
    figure.savefig(path, dpi=110, metadata={"Software": None})  # no version stamp: regenerated files compare
    plt.close(figure)
    return path


def figure_routes(routes: Sequence[BenchmarkRoute], records: Records, agents: Sequence[str]) -> list[str]:
    """Per condition, the first route with the most turns that every agent finished successfully (else any)."""
    succeeded = {key for key, record in records.items() if record.episode.success}
    ran = {route_key for _, route_key in records}
    chosen = []
    for condition in dict.fromkeys(route.condition for route in routes):
        candidates = sorted((r for r in routes if r.condition == condition and r.key in ran),
                            key=lambda r: (not all((a, r.key) in succeeded for a in agents), -len(r.junctions), r.key))
        if candidates:
            chosen.append(candidates[0].key)
    return chosen
