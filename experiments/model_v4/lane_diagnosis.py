"""Why the decoder variants cross solid lines at junctions (issue 89, deliverable 1): experiments that can fail.

(a) **Where each crossing begins** (the committed runs' episode records and trajectories, lane_closed_loop): per
    network and condition, crossings per km in each junction phase of each junction command (approach, in, after:
    lane_places) and away from junctions; where in the junction (metres into it), on which side of the route, and
    whether the kerb followed. A network that cuts LEFT corners has its LEFT crossings on the approach or early in
    the junction, left of the route; one that runs wide has them late and right of it.
(b) **The path and the steer at those places**: the car's signed distance from the route by metres into each
    junction beside the expert's own drive of the same routes, where its heading has turned 10 and 45 degrees
    toward a turn (paired with the expert's passage of the same junction: metres earlier), and, where the run kept
    telemetry, the network's steer beside the expert's label in the same state by metres into the junction and in
    the three seconds before each crossing, and the shift that best lines the two up. A network that turns in early
    leads the expert; one that only drifts does not.
(c) **Why the decoder variants do it and MSF does not** (lane_model, held-out bags: the sample bag, and the town_h1
    bags of scripts/gate_bags.sh whose routes turn LEFT): every branch on every frame, the trunk's gradient by loss
    term, what the LEFT branch looks at (occlusion, gradient x input), where the waiting round and model v3 moved the
    weights; the committed lateral studies' figures beside them; and the training data's LEFT frames as the committed
    data reports count them (no frame of the training data is on this machine).

    python -m experiments.model_v4.lane_diagnosis --frames sample=bags/sample \\
        --frames 'gate=data/gate/test/town_h1_soft_rain_dusk_*' --out docs/results/model_v4/lane_diagnosis
    python -m experiments.model_v4.lane_diagnosis --render docs/results/model_v4/lane_diagnosis   # page, figures
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from collections.abc import Sequence
from dataclasses import asdict, fields
from pathlib import Path

import numpy as np

RECORD = "study.json"
PAGE = "README.md"
GRAPH2 = "docs/results/closed_loop_v3_graph2/records/networks"
JUDGE = "docs/results/waiting/records/judge-routes"
AEB = "docs/results/aeb_crossing_v1/records/routes_1,docs/results/aeb_crossing_v1/records/routes_2," \
      "docs/results/aeb_crossing_v1/records/routes_3"
V3 = "docs/results/closed_loop_v3_model_v3/records"
DEFAULT_SOURCES = (
    f"msfsu={GRAPH2}:msfsu", f"msf={GRAPH2}:msf", f"su={GRAPH2}:su", f"msfsu_stop={JUDGE}:msfsu_stop",
    f"msfsu (judge run)={JUDGE}:msfsu", f"msfsu (crossing-brake run)={AEB}:msfsu", f"msfsu_aeb_x={AEB}:msfsu_aeb_x",
    f"msfsu_v3={V3}/judge-msfsu:msfsu_v3", f"msf_v3={V3}/judge-msf-su:msf_v3", f"su_v3={V3}/judge-msf-su:su_v3")
DEFAULT_EXPERT = f"expert={GRAPH2}:expert"
DEFAULT_NETWORKS = ("msfsu=models/msfsu_default.pt", "msf=models/msf.pt", "su=models/su.pt",
                    "msfsu_stop=checkpoints/waiting/msfsu_stop.pt", "msfsu_v3=checkpoints/v3/msfsu.pt")
DEFAULT_WEIGHT_PAIRS = ("msfsu_stop=checkpoints/waiting/msfsu_stop.pt:models/msfsu_default.pt",
                        "msfsu_v3=checkpoints/v3/msfsu.pt:models/msfsu_default.pt",
                        "msf_v3=checkpoints/v3/msf.pt:models/msf.pt")
LATERAL_RECORDS = ("held-out bags=docs/results/closed_loop_v3_graph2/lateral/lateral_study.json",
                   "training towns' validation bags=docs/results/closed_loop_v3_graph2/lateral_train_towns/"
                   "lateral_study.json")
DATA_REPORTS = ("shipped models=docs/results/data/data.json", "model v3=docs/results/model_v3/data.json",
                "waiting (msfsu_stop)=docs/results/waiting/data.json")
DEFAULT_FRAMES = "sample=bags/sample"
MAIN = ("msfsu", "msf", "su", "msfsu_stop")  # the sources the plots show


def parse_source(text: str):
    """NAME=RUN[,RUN...]:AGENT -> lane_closed_loop.Source."""
    from experiments.model_v4.lane_closed_loop import Source

    name, separator, rest = text.partition("=")
    runs, colon, agent = rest.rpartition(":")
    if not separator or not colon or not name or not runs or not agent:
        raise argparse.ArgumentTypeError(f"expected NAME=RUN[,RUN...]:AGENT, got '{text}'")
    return Source(name, tuple(Path(run) for run in runs.split(",")), agent)


def _pair(text: str) -> tuple[str, str]:
    name, separator, value = text.partition("=")
    if not separator or not name or not value:
        raise argparse.ArgumentTypeError(f"expected NAME=VALUE, got '{text}'")
    return name, value


# ----- (a), (b): closed loop -----
def closed_loop(sources: Sequence, expert_source, cache: Path) -> dict:
    from experiments.model_v4 import lane_closed_loop as loop
    from experiments.model_v4.lane_places import load_route_lines
    from msfsu_evaluation.closed_loop.runs import relative
    from msfsu_evaluation.closed_loop.suites import load_routes

    _, routes = load_routes()
    by_key = {route.key: route for route in routes}
    lines = load_route_lines(routes, cache)
    expert = loop.source_episodes(expert_source, by_key, lines, with_telemetry=False)
    study: dict = {"sources": [], "crossing_rates": [], "crossing_places": [], "offset_profile": [],
                   "turn_in": [], "steer_profile": [], "lead_lag": [], "before_crossings": [], "crossings": [],
                   "crossing_columns": [f.name for f in fields(loop.Crossing)]}
    for source in [expert_source, *sources]:
        found = expert if source is expert_source else loop.source_episodes(source, by_key, lines)
        print(f"lane_diagnosis: {source.name}: {found.episodes} episodes, {len(found.crossings)} crossings, "
              f"{found.telemetry_episodes} with telemetry", file=sys.stderr)
        study["sources"].append({"name": source.name, "runs": [relative(run) for run in source.runs],
                                 "agent": source.agent, "episodes": found.episodes,
                                 "telemetry_episodes": found.telemetry_episodes,
                                 "place_agreement": list(found.place_agreement),
                                 "spans_checked": list(found.spans_checked), "expert": source is expert_source})
        study["crossing_rates"] += loop.crossing_rates(found)
        study["crossing_places"] += loop.crossing_places(found)
        study["offset_profile"] += loop.offset_profile(found)
        study["turn_in"] += loop.turn_in(found, None if source is expert_source else expert)
        study["steer_profile"] += loop.steer_profile(found)
        study["lead_lag"] += loop.lead_lag(found)
        study["before_crossings"] += loop.before_crossings(found)
        if source.name in MAIN:
            study["crossings"] += [list(asdict(c).values()) for c in found.crossings]
    study["spans"] = span_lengths(routes, lines)
    return study


def span_lengths(routes: Sequence, lines: dict) -> list[dict]:
    """Per condition and junction command: the junctions' lengths along the route (metres) and the share of a
    command's metres (LOOKAHEAD_M before the junction to its end) that lie before the junction."""
    from experiments.model_v4.lane_places import LOOKAHEAD_M
    from msfsu_common.road_option import RoadOption

    rows = []
    for condition in ("train", "heldout"):
        lengths: dict[str, list[float]] = {}
        seen = set()
        for route in routes:
            line = lines[route.key]
            ident = (route.town, route.start, route.lane, route.destination)
            if route.condition != condition or ident in seen:
                continue
            seen.add(ident)
            for (start, end), option in zip(line.spans(), line.junction_options()):
                lengths.setdefault(RoadOption(option).name, []).append(end - start)
        for command in ("LEFT", "STRAIGHT", "RIGHT"):
            values = np.array(lengths.get(command, []))
            if len(values):
                rows.append({"condition": condition, "command": command, "junctions": len(values),
                             "length_m_median": round(float(np.median(values)), 1),
                             "length_m_range": [round(float(values.min()), 1), round(float(values.max()), 1)],
                             "approach_share": round(float(np.mean(LOOKAHEAD_M / (LOOKAHEAD_M + values))), 3)})
    return rows


# ----- (c): the networks and the data -----
def parse_frames(text: str) -> tuple[str, list[str], int | None]:
    """NAME=BAG_OR_GLOB[,BAG_OR_GLOB...][:PER_BAG] -> (name, patterns, frames per bag or None)."""
    name, separator, rest = text.partition("=")
    patterns, colon, per_bag = rest.rpartition(":")
    if not colon or not per_bag.isdigit():
        patterns, per_bag = rest, ""
    if not separator or not name or not patterns:
        raise argparse.ArgumentTypeError(f"expected NAME=BAG[,BAG...][:PER_BAG], got '{text}'")
    return name, patterns.split(","), int(per_bag) if per_bag else None


def model_experiments(networks: Sequence[tuple[str, str]], weight_pairs: Sequence[tuple[str, str]],
                      frame_sets: Sequence[tuple[str, list[str], int | None]], cache: Path) -> dict:
    """(c) on each frame set: every branch, the gradients by loss term, the LEFT branch's inputs (rows named by their
    frame set); the weights' changes once."""
    from glob import glob

    from experiments.model_v4 import lane_model

    checkpoints = [Path(path) for _, path in networks]
    study: dict = {"networks": dict(networks), "frame_sets": [], "branches": [], "gradients": [], "occlusion": [],
                   "weights": []}
    for set_name, patterns, per_bag in frame_sets:
        bags = sorted(Path(path) for pattern in patterns for path in glob(pattern))
        if not bags:
            raise FileNotFoundError(f"no bag matches {patterns} (frame set {set_name})")
        frames = lane_model.load_frames(bags, checkpoints, cache, per_bag)
        groups = {str(g): int((frames.group == g).sum()) for g in dict.fromkeys(frames.group)}
        study["frame_sets"].append({"name": set_name, "bags": frames.names, "frames": int(len(frames.steer)),
                                    "frames_per_bag": per_bag, "frames_per_group": groups})
        for name, path in networks:
            print(f"lane_diagnosis: {name} on {len(frames.steer)} frames of {set_name}", file=sys.stderr)
            tag = lambda rows: [{"frame_set": set_name, **row} for row in rows]  # noqa: E731
            study["branches"] += tag(lane_model.branches(name, lane_model.branch_outputs(Path(path), frames), frames))
            study["gradients"] += tag(lane_model.gradients(name, Path(path), frames))
            study["occlusion"] += tag(lane_model.occlusion(name, Path(path), frames))
    for name, pair in weight_pairs:
        checkpoint, _, base = pair.partition(":")
        study["weights"] += lane_model.weights(name, Path(checkpoint), Path(base))
    return study


def lateral_records(records: Sequence[tuple[str, str]]) -> list[dict]:
    """The committed lateral studies (msfsu_evaluation.lateral_study, thousands of frames the sample bag does not
    have): per network, the LEFT approach's signed error through the LEFT branch and through the other branches, the
    LEFT branch on the RIGHT approach, and the scene gradient against the control gradient on the LEFT frames."""
    rows = []
    for name, path in records:
        record = json.loads(Path(path).read_text())
        for network in record["networks"]:
            row = {"frames": name, "source": path, "network": network}
            for item in record["branches"]:
                if item["network"] == network:
                    row[f"{item['group']} / {item['branch']} branch"] = [round(item["signed"], 4),
                                                                         [round(v, 4) for v in item["signed_ci95"]],
                                                                         item["frames"]]
            for item in record["gradients"]:
                if item["network"] == network and item["frames_of"] == "LEFT":
                    row["LEFT gradients"] = {"scene_over_control": round(item["ratio"], 3),
                                             "cosine": round(item["cosine"], 3), "frames": item["frames"]}
            rows.append(row)
    return rows


def data_composition(reports: Sequence[tuple[str, str]]) -> list[dict]:
    """Per data report, split and round: frames per command, the LEFT share, the bags with LEFT frames and their LEFT
    frames per bag (a LEFT command lasts one junction: its approach and the turn, waits included)."""
    rows = []
    for name, path in reports:
        record = json.loads(Path(path).read_text())
        groups: dict[tuple[str, int], list[dict]] = {}
        for bag in record["bags"]:
            groups.setdefault((bag["split"], bag["round"]), []).append(bag)
        for (split, round_), bags in sorted(groups.items()):
            commands = {command: sum(bag["commands"].get(command, 0) for bag in bags)
                        for command in ("LEFT", "RIGHT", "STRAIGHT", "LANE_FOLLOW")}
            left_bags = [bag["commands"]["LEFT"] for bag in bags if bag["commands"].get("LEFT")]
            total = sum(commands.values())
            rows.append({"data": name, "source": path, "split": split, "round": round_, "bags": len(bags),
                         "frames": total, "commands": commands,
                         "left_share": round(commands["LEFT"] / total, 3) if total else None,
                         "bags_with_left": len(left_bags),
                         "left_frames_per_bag_median": float(np.median(left_bags)) if left_bags else None,
                         "network_frames": sum(bag.get("network_frames", 0) for bag in bags)})
    return rows


def dump(study: dict) -> str:
    """The record as JSON, indented, with every list of plain values on one line."""
    import re

    text = json.dumps(study, indent=1)
    return re.sub(r"\[\s+([^\[\]{}]*?)\s+\]", lambda match: "[" + re.sub(r"\s*\n\s*", " ", match.group(1)) + "]",
                  text) + "\n"


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m experiments.model_v4.lane_diagnosis",
                                     description=__doc__.splitlines()[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter, epilog=__doc__)
    parser.add_argument("--source", action="append", type=parse_source, default=None,
                        metavar="NAME=RUN[,RUN...]:AGENT", help=f"a network's episodes (default: {DEFAULT_SOURCES})")
    parser.add_argument("--expert", type=parse_source, default=None, metavar="NAME=RUN[,RUN...]:AGENT",
                        help=f"the expert's episodes of the same routes (default: {DEFAULT_EXPERT})")
    parser.add_argument("--network", action="append", type=_pair, default=None, metavar="NAME=CHECKPOINT",
                        help=f"a network for (c) (default: {DEFAULT_NETWORKS})")
    parser.add_argument("--weights", action="append", type=_pair, default=None, metavar="NAME=CHECKPOINT:BASE",
                        help=f"a checkpoint and the one it was warm-started from (default: {DEFAULT_WEIGHT_PAIRS})")
    parser.add_argument("--frames", action="append", type=parse_frames, default=None,
                        metavar="NAME=BAG[,BAG...][:PER_BAG]",
                        help=f"a set of held-out bags (globs) for (c), at most PER_BAG frames of each, evenly spaced "
                             f"(default: {DEFAULT_FRAMES})")
    parser.add_argument("--data", action="append", type=_pair, default=None, metavar="NAME=DATA_JSON",
                        help=f"data reports (default: {DATA_REPORTS})")
    parser.add_argument("--lateral", action="append", type=_pair, default=None, metavar="NAME=LATERAL_STUDY_JSON",
                        help=f"committed lateral studies to set beside (c) (default: {LATERAL_RECORDS})")
    parser.add_argument("--skip-model", action="store_true", help="leave (c)'s network experiments out")
    parser.add_argument("--cache", type=Path, default=Path("runs/cache/lane_diagnosis"))
    parser.add_argument("--out", type=Path)
    parser.add_argument("--render", type=Path, metavar="DIR",
                        help=f"write DIR's page and figures again from its {RECORD}")
    options = parser.parse_args(argv)
    from experiments.model_v4.lane_page import plot, render

    if options.render:
        study = json.loads((options.render / RECORD).read_text())
        study["figures"] = plot(study, options.render)
        (options.render / RECORD).write_text(dump(study))
        (options.render / PAGE).write_text(render(study))
        return 0
    if options.out is None:
        parser.error("give --out DIR (or --render DIR)")
    import torch

    from msfsu_common.benchmark_run import BenchmarkRun

    torch.set_num_threads(1)
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    started = BenchmarkRun.start("python -m experiments.model_v4.lane_diagnosis", argv, quoted=True)
    expert = options.expert or parse_source(DEFAULT_EXPERT)
    sources = options.source or [parse_source(text) for text in DEFAULT_SOURCES]
    study: dict = closed_loop(sources, expert, options.cache / "route_lines.json")
    study["data"] = data_composition(options.data or [_pair(text) for text in DATA_REPORTS])
    study["lateral"] = lateral_records(options.lateral or [_pair(text) for text in LATERAL_RECORDS])
    if not options.skip_model:
        networks = options.network or [_pair(text) for text in DEFAULT_NETWORKS]
        pairs = options.weights or [_pair(text) for text in DEFAULT_WEIGHT_PAIRS]
        study["model"] = model_experiments(networks, pairs, options.frames or [parse_frames(DEFAULT_FRAMES)],
                                           options.cache / "frames")
    study["run"] = asdict(started.end())
    options.out.mkdir(parents=True, exist_ok=True)
    study["figures"] = plot(study, options.out)
    (options.out / RECORD).write_text(dump(study))
    (options.out / PAGE).write_text(render(study))
    return 0


if __name__ == "__main__":
    sys.exit(main())
