"""The committed closed-loop runs, junction by junction: where each solid-line crossing began, the path beside the
route and the expert's, and (where the run kept telemetry) the network's steer beside the expert's label.

Every episode's trajectory is replayed along its route (lane_places.follow: the simulator's own progress), so each
step and each crossing gets a Place (junction phase, metres into the junction) and a side (signed distance from the
route's polyline, positive right). A junction passage is one episode's steps from LOOKAHEAD_M before a junction to
AFTER_M past it. Intervals are 95 % bootstrap intervals over routes (per-km rates: stopping_study.bootstrap_ratio of
crossings over metres) or over passages (means: lateral_study.cluster_bootstrap), since the steps of one passage,
and the crossings of one route, are not independent.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from experiments.model_v4.lane_places import (AFTER_M, LOOKAHEAD_M, RouteLine, follow, junction_place, turn_in_m,
                                              unwrap_from)
from msfsu_common.road_option import RoadOption

JUNCTION_COMMANDS = ("LEFT", "STRAIGHT", "RIGHT")
BIN_EDGES_M = (-15.0, -10.0, -5.0, 0.0, 5.0, 10.0, 15.0, 20.0, 25.0, 30.0, 40.0, 50.0)
TURN_IN_DEGREES = (10.0, 45.0)  # heading turned toward the turn since the approach began
WINDOWS_S = ((-3.0, -2.0), (-2.0, -1.0), (-1.0, 0.0))  # before a crossing began
KERB_WITHIN_S = 3.0  # a kerb strike this soon after a crossing ended the episode: the crossing's
MAX_LAG_STEPS = 20  # 2 s
BEND_M = 10.0  # the route's bend at a crossing: its heading change from this far before to this far after
BEND_DEG = 5.0  # a bend of at least this many degrees counts as one
TOWARD = {"LEFT": 1, "RIGHT": -1}


@dataclass(frozen=True)
class Source:
    """One network's episodes: `agent` in the run directories `runs`, under the page's `name`."""

    name: str
    runs: tuple[Path, ...]
    agent: str


@dataclass(frozen=True)
class Crossing:
    source: str
    route: str
    condition: str
    time_s: float
    command: str  # in force, as recorded
    recorded_place: str  # the record's (lane_follow, junction_approach, junction)
    phase: str  # lane_places.PHASES
    junction_command: str | None  # the command of the junction whose phase it is
    into_m: float | None
    span_m: float | None  # the junction's length
    offset_m: float  # signed distance from the route, positive right
    heading_error_deg: float  # the car's yaw minus the route's, positive left
    kerb_after: bool  # the episode ended on the kerb within KERB_WITHIN_S
    bend_deg: float  # the route's heading change from BEND_M before the crossing to BEND_M after (positive: left)
    network_steer: tuple[float | None, ...] | None = None  # per WINDOWS_S, telemetry only
    expert_steer: tuple[float | None, ...] | None = None


@dataclass
class Passage:
    """One junction driven by one source (arrays of its steps)."""

    source: str
    route: str
    junction: int
    command: str
    into_m: np.ndarray
    offset_m: np.ndarray
    heading_change_rad: np.ndarray
    network_steer: np.ndarray | None = None
    expert_steer: np.ndarray | None = None
    turn_in_m: dict[float, float | None] = field(default_factory=dict)


@dataclass
class SourceEpisodes:
    """What one source's episodes gave."""

    source: str
    crossings: list[Crossing]
    passages: list[Passage]
    metres: dict[tuple[str, str, str], float]  # (route, junction command or "-", phase) -> metres driven
    route_conditions: dict[str, str]
    telemetry_episodes: int
    episodes: int
    place_agreement: tuple[int, int]  # crossings whose place agrees with the record's, of those compared
    spans_checked: tuple[int, int]  # episodes whose junctions match the route file's, of all


_RECORDED = {"approach": "junction_approach", "in": "junction"}


def _window_means(time: np.ndarray, values: np.ndarray, at: float) -> tuple[float | None, ...]:
    means = []
    for low, high in WINDOWS_S:
        inside = (time >= at + low - 1e-6) & (time < at + high - 1e-6) & np.isfinite(values)
        means.append(round(float(values[inside].mean()), 4) if inside.any() else None)
    return tuple(means)


def episode_places(source: str, record, route, line: RouteLine, with_telemetry: bool = True
                   ) -> tuple[list[Crossing], list[Passage], dict, bool, tuple[int, int], bool]:
    """One episode: (crossings, passages, metres by (junction command, phase), spans match the route file,
    (place agreements, compared), telemetry used)."""
    episode = record.episode
    trajectory = record.trajectory()
    time, xy, yaw = trajectory[:, 0], trajectory[:, 1:3], trajectory[:, 3]
    followed = follow(line, xy, yaw)
    progress = followed.progress_m
    start = float(progress[0])
    spans = line.spans()
    options = [RoadOption(value).name for value in line.junction_options()]
    spans_match = options == list(route.junctions)
    places = [junction_place(p, spans) for p in progress]
    metres: dict[tuple[str, str], float] = {}
    for step in range(1, len(progress)):
        place = places[step - 1]
        key = (options[place.junction] if place.junction is not None else "-", place.phase)
        metres[key] = metres.get(key, 0.0) + max(float(progress[step] - progress[step - 1]), 0.0)
    telemetry = record.telemetry() if with_telemetry else None
    network = expert = None
    if telemetry is not None and len(telemetry) <= len(time):
        network = np.full(len(time), np.nan)
        expert = np.full(len(time), np.nan)
        network[:len(telemetry)] = telemetry.column("action_steer")
        expert[:len(telemetry)] = telemetry.column("expert_steer")
    kerb = episode.status == "collision" and episode.collision_type == "sidewalk"
    crossings, agreed = [], [0, 0]
    for crossing in episode.solid_lines or ():
        step = int(np.argmin(np.abs(time - crossing.time_s)))
        place = junction_place(start + crossing.progress_m, spans)
        span = spans[place.junction] if place.junction is not None else None
        if place.phase != "after":  # the record has no exit place: it is lane_follow or the next approach there
            agreed[1] += 1
            agreed[0] += _RECORDED.get(place.phase, "lane_follow") == crossing.where
        crossings.append(Crossing(
            source, episode.route, route.condition, crossing.time_s, crossing.command, crossing.where, place.phase,
            options[place.junction] if place.junction is not None else None,
            None if place.into_m is None else round(place.into_m, 1),
            None if span is None else round(span[1] - span[0], 1), round(float(followed.offset_m[step]), 2),
            round(math.degrees(float(followed.heading_error_rad[step])), 1),
            kerb and episode.time_s - crossing.time_s <= KERB_WITHIN_S,
            round(math.degrees(_wrap(_route_heading(line, start + crossing.progress_m + BEND_M)
                                     - _route_heading(line, start + crossing.progress_m - BEND_M))), 1),
            None if network is None else _window_means(time, network, crossing.time_s),
            None if expert is None else _window_means(time, expert, crossing.time_s)))
    passages = []
    for index, (begin, end) in enumerate(spans):
        inside = (progress >= begin - LOOKAHEAD_M) & (progress < end + AFTER_M)
        if inside.sum() < 3:
            continue
        steps = np.flatnonzero(inside)
        heading_at_approach = _route_heading(line, begin - LOOKAHEAD_M)
        passage = Passage(source, episode.route, index, options[index], progress[steps] - begin,
                          followed.offset_m[steps], unwrap_from(yaw[steps], heading_at_approach),
                          None if network is None else network[steps], None if expert is None else expert[steps])
        if options[index] in TOWARD and progress[steps[-1]] >= end:  # a turn driven through
            passage.turn_in_m = {degrees: turn_in_m(passage.into_m, passage.heading_change_rad,
                                                    TOWARD[options[index]], degrees) for degrees in TURN_IN_DEGREES}
        passages.append(passage)
    return crossings, passages, metres, spans_match, tuple(agreed), network is not None


def _wrap(angle: float) -> float:
    return (angle + math.pi) % (2 * math.pi) - math.pi


def _route_heading(line: RouteLine, arc_m: float) -> float:
    points = np.asarray(line.points, np.float64)
    cumulative = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(points, axis=0), axis=1))])
    segment = min(max(int(np.searchsorted(cumulative, max(arc_m, 0.0), side="right")) - 1, 0), len(points) - 2)
    dx, dy = points[segment + 1] - points[segment]
    return math.atan2(dy, dx)


def source_episodes(source: Source, routes: Mapping[str, object], lines: Mapping[str, RouteLine],
                    with_telemetry: bool = True) -> SourceEpisodes:
    from msfsu_evaluation.closed_loop.runs import merge

    crossings, passages, metres, conditions = [], [], {}, {}
    agreed, matched, telemetry_episodes, episodes = [0, 0], [0, 0], 0, 0
    for (_, route_key), record in sorted(merge(list(source.runs), {source.agent}).items()):
        if route_key not in routes:
            continue
        route = routes[route_key]
        found, driven, by_place, match, agreement, used = episode_places(source.name, record, route,
                                                                         lines[route_key], with_telemetry)
        crossings += found
        passages += driven
        for (command, phase), value in by_place.items():
            metres[(route_key, command, phase)] = metres.get((route_key, command, phase), 0.0) + value
        conditions[route_key] = route.condition
        agreed = [agreed[0] + agreement[0], agreed[1] + agreement[1]]
        matched = [matched[0] + match, matched[1] + 1]
        telemetry_episodes += used
        episodes += 1
    return SourceEpisodes(source.name, crossings, passages, metres, conditions, telemetry_episodes, episodes,
                          tuple(agreed), tuple(matched))


# ----- the tables -----
def interval(values: np.ndarray, clusters: np.ndarray) -> list[float] | None:
    """95 % bootstrap interval of the mean, resampling whole clusters (lateral_study.cluster_bootstrap); None for
    fewer than two values or clusters."""
    from msfsu_evaluation.lateral_study import cluster_bootstrap

    if len(values) < 2 or len(np.unique(clusters)) < 2:
        return None
    return [round(bound, 4) for bound in cluster_bootstrap(np.asarray(values, np.float64), np.asarray(clusters))]


def rate(crossings: Sequence[Crossing], metres: Mapping[tuple[str, str, str], float], routes: Sequence[str],
         keep=lambda crossing: True, where=lambda command, phase: True) -> dict:
    """Crossings per km over `routes` (those `keep` picks, over the metres whose (junction command, phase) `where`
    picks), with the 95 % bootstrap interval over routes."""
    from msfsu_evaluation.stopping_study import bootstrap_ratio

    hits = np.array([sum(1 for c in crossings if c.route == route and keep(c)) for route in routes], np.float64)
    km = np.array([sum(value for (r, command, phase), value in metres.items() if r == route and where(command, phase))
                   for route in routes], np.float64) / 1000.0
    total = float(km.sum())
    interval = bootstrap_ratio(hits, km) if total > 0 else None
    return {"crossings": int(hits.sum()), "km": round(total, 2),
            "per_km": round(float(hits.sum()) / total, 3) if total > 0 else None,
            "ci95": None if interval is None else [round(interval[0], 3), round(interval[1], 3)]}


def crossing_rates(found: SourceEpisodes) -> list[dict]:
    """Per condition: all crossings per km, and per (junction command, phase) and away."""
    rows = []
    for condition in ("train", "heldout"):
        routes = sorted(route for route, c in found.route_conditions.items() if c == condition)
        if not routes:
            continue
        ours = [c for c in found.crossings if c.condition == condition]
        row = {"source": found.source, "condition": condition, "routes": len(routes),
               "all": rate(ours, found.metres, routes)}
        for command in JUNCTION_COMMANDS:
            for phase in ("approach", "in", "after"):
                row[f"{command} {phase}"] = rate(
                    ours, found.metres, routes, lambda c, command=command, phase=phase: (
                        c.junction_command == command and c.phase == phase),
                    lambda m, p, command=command, phase=phase: m == command and p == phase)
        row["away"] = rate(ours, found.metres, routes, lambda c: c.phase == "away", lambda m, p: p == "away")
        rows.append(row)
    return rows


def crossing_places(found: SourceEpisodes) -> list[dict]:
    """Per junction command (and away): where the crossings began: metres into the junction, the side, the kerb."""
    rows = []
    for command in (*JUNCTION_COMMANDS, None):
        ours = [c for c in found.crossings if c.junction_command == command]
        if not ours:
            continue
        into = np.array([c.into_m for c in ours if c.into_m is not None], np.float64)
        share = lambda values: round(float(np.mean(values)), 3) if len(values) else None  # noqa: E731
        rows.append({
            "source": found.source, "junction_command": command or "away", "crossings": len(ours),
            "routes": len({c.route for c in ours}),
            "by_phase": {phase: sum(1 for c in ours if c.phase == phase) for phase in ("approach", "in", "after",
                                                                                       "away")},
            "into_m_quartiles": [round(float(q), 1) for q in np.percentile(into, (25, 50, 75))] if len(into) else None,
            "into_share_of_span_median": (round(float(np.median([c.into_m / c.span_m for c in ours
                                                                if c.into_m is not None and c.span_m])), 2)
                                          if len(into) else None),
            "left_share": share([c.offset_m < 0 for c in ours]),
            "offset_m_median": round(float(np.median([c.offset_m for c in ours])), 2),
            "heading_error_deg_median": round(float(np.median([c.heading_error_deg for c in ours])), 1),
            "kerb_after": sum(c.kerb_after for c in ours),
            "bends": {"left": sum(c.bend_deg >= BEND_DEG for c in ours),
                      "straight": sum(abs(c.bend_deg) < BEND_DEG for c in ours),
                      "right": sum(c.bend_deg <= -BEND_DEG for c in ours)},
            "recorded_commands": {name: sum(1 for c in ours if c.command == name)
                                  for name in sorted({c.command for c in ours})}})
    return rows


def offset_profile(found: SourceEpisodes) -> list[dict]:
    """Per junction command and bin of metres into the junction: the mean signed offset from the route (interval over
    passages), the share of passages more than 0.5 m left of it."""
    rows = []
    for command in JUNCTION_COMMANDS:
        ours = [p for p in found.passages if p.command == command]
        if not ours:
            continue
        for low, high in zip(BIN_EDGES_M[:-1], BIN_EDGES_M[1:]):
            means, clusters = [], []
            for passage in ours:
                inside = (passage.into_m >= low) & (passage.into_m < high)
                if inside.any():
                    means.append(float(passage.offset_m[inside].mean()))
                    clusters.append(passage.route)
            if len(means) < 2:
                continue
            values = np.array(means)
            rows.append({"source": found.source, "command": command, "bin": [low, high], "passages": len(means),
                         "offset_m": round(float(values.mean()), 3), "ci95": interval(values, np.array(clusters)),
                         "left_of_0_5m_share": round(float(np.mean(values < -0.5)), 3)})
    return rows


def turn_in(found: SourceEpisodes, expert: SourceEpisodes | None) -> list[dict]:
    """Per turn command and TURN_IN_DEGREES: where the heading had turned that far (metres into the junction), and
    paired with the expert's passage of the same route and junction, how many metres earlier the source got there
    (positive: it turned in earlier than the expert)."""
    reference = {} if expert is None else {(p.route, p.junction): p.turn_in_m for p in expert.passages}
    rows = []
    for command in TOWARD:
        ours = [p for p in found.passages if p.command == command and p.turn_in_m]
        for degrees in TURN_IN_DEGREES:
            points = [(p.route, p.turn_in_m[degrees]) for p in ours if p.turn_in_m.get(degrees) is not None]
            paired = [(p.route, reference[(p.route, p.junction)][degrees] - p.turn_in_m[degrees]) for p in ours
                      if p.turn_in_m.get(degrees) is not None and reference.get((p.route, p.junction), {}).get(degrees)
                      is not None]
            if not points:
                continue
            at = np.array([value for _, value in points])
            lead = np.array([value for _, value in paired])
            rows.append({"source": found.source, "command": command, "degrees": degrees, "passages": len(points),
                         "at_m_median": round(float(np.median(at)), 1),
                         "at_m_mean": round(float(at.mean()), 2),
                         "at_ci95": interval(at, np.array([r for r, _ in points])),
                         "paired": len(paired),
                         "earlier_than_expert_m_mean": round(float(lead.mean()), 2) if len(lead) else None,
                         "earlier_ci95": interval(lead, np.array([r for r, _ in paired])) if len(lead) else None,
                         "earlier_share": round(float(np.mean(lead > 0.5)), 3) if len(lead) else None})
    return rows


def steer_profile(found: SourceEpisodes) -> list[dict]:
    """Telemetry only: per junction command and bin, the network's steer and the expert's label in the same state
    (means over passages, the difference's interval over passages), and the spread of each over the steps."""
    rows = []
    for command in JUNCTION_COMMANDS:
        ours = [p for p in found.passages if p.command == command and p.network_steer is not None]
        if not ours:
            continue
        for low, high in zip(BIN_EDGES_M[:-1], BIN_EDGES_M[1:]):
            net, exp, diff, clusters, steps_net, steps_exp = [], [], [], [], [], []
            for passage in ours:
                inside = ((passage.into_m >= low) & (passage.into_m < high) & np.isfinite(passage.network_steer)
                          & np.isfinite(passage.expert_steer))
                if inside.any():
                    net.append(float(passage.network_steer[inside].mean()))
                    exp.append(float(passage.expert_steer[inside].mean()))
                    diff.append(net[-1] - exp[-1])
                    clusters.append(passage.route)
                    steps_net.append(passage.network_steer[inside])
                    steps_exp.append(passage.expert_steer[inside])
            if len(diff) < 2:
                continue
            all_net, all_exp = np.concatenate(steps_net), np.concatenate(steps_exp)
            rows.append({"source": found.source, "command": command, "bin": [low, high], "passages": len(diff),
                         "steps": int(len(all_net)), "network": round(float(np.mean(net)), 4),
                         "expert": round(float(np.mean(exp)), 4), "difference": round(float(np.mean(diff)), 4),
                         "difference_ci95": interval(np.array(diff), np.array(clusters)),
                         "network_std": round(float(all_net.std()), 4), "expert_std": round(float(all_exp.std()), 4)})
    return rows


def lead_lag(found: SourceEpisodes) -> list[dict]:
    """Telemetry only: per junction command, the shift that best lines the network's steer up with the expert's label
    over each passage (lane_places.lead_lag_steps; positive: the network leads)."""
    from experiments.model_v4.lane_places import lead_lag_steps

    rows = []
    for command in JUNCTION_COMMANDS:
        lags, clusters = [], []
        for passage in found.passages:
            if passage.command != command or passage.network_steer is None:
                continue
            lag = lead_lag_steps(passage.network_steer, passage.expert_steer, MAX_LAG_STEPS)
            if lag is not None:
                lags.append(lag)
                clusters.append(passage.route)
        if len(lags) < 2:
            continue
        values = np.array(lags, np.float64)
        rows.append({"source": found.source, "command": command, "passages": len(lags),
                     "lag_steps_median": float(np.median(values)), "lag_steps_mean": round(float(values.mean()), 2),
                     "ci95": interval(values, np.array(clusters)), "leads_share": round(float(np.mean(values > 0)), 3),
                     "lags_share": round(float(np.mean(values < 0)), 3)})
    return rows


def before_crossings(found: SourceEpisodes) -> list[dict]:
    """Telemetry only: per junction command, the network's steer and the expert's label in the seconds before each
    crossing (WINDOWS_S), means over crossings, the difference's interval over routes."""
    rows = []
    for command in (*JUNCTION_COMMANDS, None):
        ours = [c for c in found.crossings if c.junction_command == command and c.network_steer is not None]
        if not ours:
            continue
        row = {"source": found.source, "junction_command": command or "away", "crossings": len(ours), "windows": []}
        for index, window in enumerate(WINDOWS_S):
            pairs = [(c.network_steer[index], c.expert_steer[index], c.route) for c in ours
                     if c.network_steer[index] is not None and c.expert_steer[index] is not None]
            if not pairs:
                continue
            net = np.array([a for a, _, _ in pairs])
            exp = np.array([b for _, b, _ in pairs])
            row["windows"].append({"window_s": list(window), "crossings": len(pairs),
                                   "network": round(float(net.mean()), 4), "expert": round(float(exp.mean()), 4),
                                   "difference": round(float((net - exp).mean()), 4),
                                   "difference_ci95": interval(net - exp, np.array([r for _, _, r in pairs])),
                                   "network_left_of_expert_share": round(float(np.mean(net < exp)), 3)})
        rows.append(row)
    return rows
