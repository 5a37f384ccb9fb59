"""Solid-line crossings by the command in force and the place on the route, per km driven there.

Episode records since the crossing places were recorded hold each crossing's start (`solid_lines`: command and
place, episode.RouteDistances) and the route progress driven under each command and in each place
(`metres_by_command`, `metres_by_place`); a record without the metres (None: not recorded) is left out here (the total
per km stays in the infractions table). A rate is crossings / km driven under that command or in that place, pooled
over the episodes of an agent and condition.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence

from msfsu_common.road_option import RoadOption
from msfsu_evaluation.closed_loop.episode_record import EpisodeResult, SolidLineCrossing

COMMANDS = tuple(option.name for option in (RoadOption.LEFT, RoadOption.RIGHT, RoadOption.STRAIGHT,
                                            RoadOption.LANE_FOLLOW))
SOLID_LINE_PLACES = ("lane_follow", "junction_approach", "junction")


def place_on_route(progress_m: float, junction_spans: Sequence[tuple[float, float]], lookahead_m: float) -> str:
    """Where on the route an arc length lies: inside a junction (a span of junction segments), on its approach (within
    the route tracker's look-ahead before it, where the turn is already announced) or elsewhere (lane_follow)."""
    for start, end in junction_spans:
        if start <= progress_m < end:
            return "junction"
        if start - lookahead_m <= progress_m < start:
            return "junction_approach"
    return "lane_follow"


def _rates(crossings: Mapping[str, int], metres: Mapping[str, float], keys: Sequence[str]) -> dict[str, dict]:
    return {key: {"crossings": crossings.get(key, 0), "km": round(metres.get(key, 0.0) / 1000.0, 3),
                  "per_km": round(crossings.get(key, 0) / (metres[key] / 1000.0), 3) if metres.get(key) else None}
            for key in keys}


def _pooled(members: Sequence[EpisodeResult], metres_of: Callable[[EpisodeResult], Mapping[str, float]],
            key_of: Callable[[SolidLineCrossing], str]) -> tuple[dict[str, int], dict[str, float]]:
    """Crossings and metres per key (command or place) summed over the episodes."""
    crossings: dict[str, int] = {}
    metres: dict[str, float] = {}
    for episode in members:
        for key, value in metres_of(episode).items():
            metres[key] = metres.get(key, 0.0) + value
        for crossing in episode.solid_lines:
            crossings[key_of(crossing)] = crossings.get(key_of(crossing), 0) + 1
    return crossings, metres


def solid_line_summary(episodes: Sequence[EpisodeResult], condition_of: Mapping[str, str]) -> dict:
    """{agent: {condition: {"episodes", "by_command", "by_place"}}} over the episodes that recorded places."""
    groups: dict[tuple[str, str], list[EpisodeResult]] = {}
    for episode in episodes:
        if episode.metres_by_command is not None and episode.route in condition_of:
            groups.setdefault((episode.agent, condition_of[episode.route]), []).append(episode)
    summary: dict = {}
    for (agent, condition), members in sorted(groups.items()):
        by_command = _pooled(members, lambda episode: episode.metres_by_command, lambda crossing: crossing.command)
        by_place = _pooled(members, lambda episode: episode.metres_by_place, lambda crossing: crossing.where)
        summary.setdefault(agent, {})[condition] = {
            "episodes": len(members), "by_command": _rates(*by_command, COMMANDS),
            "by_place": _rates(*by_place, SOLID_LINE_PLACES)}
    return summary


def _cell(rate: Mapping) -> str:
    return "–" if rate["per_km"] is None else f"{rate['per_km']:.2f} ({rate['crossings']} / {rate['km']:.1f} km)"


def solid_line_markdown(summary: Mapping[str, Mapping[str, dict]]) -> list[str]:
    """The section of a report: one row per agent and condition, crossings per km by command, then by place."""
    if not summary:
        return []
    header = ["Agent", "Condition", "episodes", *COMMANDS, *SOLID_LINE_PLACES]
    lines = ["## Solid-line crossings by command and place", "",
             "Crossings per km driven under each command and in each place on the route (crossings / km there): "
             "junction_approach is the stretch before a junction where its turn is already announced (the route "
             "tracker's look-ahead), junction the junction itself.", "",
             "| " + " | ".join(header) + " |", "|" + " --- |" * len(header)]
    for agent, conditions in summary.items():
        for condition, x in conditions.items():
            cells = [_cell(x["by_command"][key]) for key in COMMANDS] + [_cell(x["by_place"][key])
                                                                          for key in SOLID_LINE_PLACES]
            lines.append(f"| {agent} | {condition} | {x['episodes']} | " + " | ".join(cells) + " |")
    return lines + [""]
