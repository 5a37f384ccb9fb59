"""Why the car does not stop for what it sees: experiments that can fail, on records and held-out bags.

1. **Pedestrian collisions, closed loop** (the episodes' telemetry, closed_loop.telemetry): for every collision of an
   agent with a pedestrian, over its last WINDOW_S seconds, where the pedestrian was (in the camera's view, in the
   network's crop, how many input pixels high, how much of it the depth image shows), what the network asked for and
   what the expert asked for in the same state, and whether the car had slowed below CREEP_MPS and moved on (a creep).
2. **Recall of vehicle_or_pedestrian by distance** (held-out bags, open loop): of the pixels the ground truth labels
   vehicle_or_pedestrian at the network's input size, the share the network labels so, by the ground truth's depth
   in BANDS_M, with a 95 % bootstrap interval over frames. A network that misses what is 8-15 m ahead shows it here.
3. **The target speed where the expert stops**: on frames (open loop) and steps (closed loop) whose expert label is
   below the control's stop speed (STOP_SPEED_MPS), the network's target speed; and on frames where the network asks
   for a creep (CREEP_BAND_MPS), the expert's labels: if those split into stops and drives, the creep is the mean of a
   two-mode label (a regression to the middle), if they sit at the creep speed the expert asked for it.

    python -m msfsu_evaluation.stopping_study --bags 'data/gate/test/*' --network msfsu=models/msfsu_default.pt \\
        --runs docs/results/abilities_v1/records/baseline --agent msfsu --out docs/results/stopping_study
    python -m msfsu_evaluation.stopping_study --render docs/results/stopping_study   # the page from study.json
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import sys
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from msfsu_common.driving import STOP_SPEED_MPS

WINDOW_S = 3.0
CREEP_MPS = 0.5  # below this the car had (nearly) stopped
CREEP_LOOKBACK_S = 15.0  # a creep is looked for in the episode's last seconds
CREEP_MOVED_M = 1.0  # and the car moved on at least this far after it first slowed (it did not stand and get hit)
CREEP_BAND_MPS = (STOP_SPEED_MPS, 1.5)  # a target speed that keeps the car creeping
DRIVE_MPS = 3.0  # an expert label above this is a drive
BANDS_M = ((0.0, 5.0), (5.0, 10.0), (10.0, 20.0), (20.0, 40.0))
BOOTSTRAP = 1000
RECORD = "study.json"
PAGE = "README.md"


@dataclass(frozen=True)
class Collision:
    """One pedestrian collision's last WINDOW_S seconds."""

    agent: str
    route: str
    actor: str
    steps: int
    in_view_share: float  # of the window's steps, the hit pedestrian... (the nearest one ahead) in the camera's view
    in_crop_share: float
    first_in_crop_s: float | None  # seconds before the end it was first in the crop (within the window)
    max_height_px: float
    mean_visible: float | None
    network_target_mps: float  # mean over the window
    expert_target_mps: float | None
    expert_stop_share: float | None  # steps whose expert label was below STOP_SPEED_MPS
    min_speed_mps: float
    crept: bool  # slowed below CREEP_MPS, then moved on into it (creep())


@dataclass(frozen=True)
class BandRecall:
    network: str
    band: str
    pixels: int
    recall: float | None
    ci95: tuple[float, float] | None


@dataclass(frozen=True)
class StopTargets:
    """The network's target speed where the expert stops, and the expert's labels where the network creeps."""

    source: str  # "closed loop: <runs>" or "open loop: <network>"
    stop_frames: int
    target_mean: float | None
    target_median: float | None
    above_stop_share: float | None  # of those frames, the share whose target keeps the car moving (>= STOP_SPEED_MPS)
    creep_frames: int
    creep_expert_stop_share: float | None  # of the creep frames, the expert's labels below STOP_SPEED_MPS ...
    creep_expert_drive_share: float | None  # ... above DRIVE_MPS
    creep_expert_between_share: float | None  # ... in between (the expert itself asks for a creep)


# ----- closed loop -----
def _share(mask: np.ndarray) -> float:
    return float(np.mean(mask)) if mask.size else math.nan


def creep(time: np.ndarray, speed: np.ndarray) -> bool:
    """Whether the car crept into what it hit: within the last CREEP_LOOKBACK_S seconds (after the episode's first
    second, the start from rest) it slowed below CREEP_MPS, and from the first such step to the collision it still
    moved CREEP_MOVED_M or more. A car standing when hit, or one that never slowed, did not creep."""
    slow = np.flatnonzero((time >= time[-1] - CREEP_LOOKBACK_S) & (time > time[0] + 1.0) & (speed < CREEP_MPS))
    if not len(slow):
        return False
    after = slice(slow[0], None)
    moved = float(np.sum(np.diff(time[after]) * (speed[after][1:] + speed[after][:-1]) / 2))
    return moved >= CREEP_MOVED_M


def collisions(runs: Sequence[Path], agent: str) -> tuple[list[Collision], int]:
    """(pedestrian collisions of `agent` with telemetry, those without)."""
    from msfsu_evaluation.closed_loop.runs import merge

    found, missing = [], 0
    for (name, route), record in sorted(merge(runs, {agent}).items()):
        episode = record.episode
        if episode.status != "collision" or episode.collision_type != "pedestrian":
            continue
        telemetry = record.telemetry()
        if telemetry is None:
            missing += 1
            continue
        time = telemetry.column("time_s")
        window = time >= time[-1] - WINDOW_S - 1e-6
        column = lambda name: telemetry.column(name)[window]  # noqa: E731
        in_crop = column("pedestrian_in_crop") == 1
        times_in_crop = time[window][in_crop]
        speed = telemetry.column("speed_mps")
        crept = creep(time, speed)
        expert = column("expert_target_speed_mps")
        visible = column("pedestrian_visible")[in_crop]
        heights = column("pedestrian_height_px")
        found.append(Collision(
            name, route, episode.collision_actor or "", int(window.sum()),
            _share(column("pedestrian_in_view") == 1), _share(in_crop),
            round(float(time[-1] - times_in_crop[0]), 1) if len(times_in_crop) else None,
            float(np.nanmax(heights)) if np.isfinite(heights).any() else 0.0,
            float(np.nanmean(visible)) if np.isfinite(visible).any() else None,
            float(np.nanmean(column("action_target_speed_mps"))),
            float(np.nanmean(expert)) if np.isfinite(expert).any() else None,
            _share(expert[np.isfinite(expert)] < STOP_SPEED_MPS) if np.isfinite(expert).any() else None,
            float(np.min(speed[window])), crept))
    return found, missing


def stop_targets(network: np.ndarray, expert: np.ndarray, source: str) -> StopTargets:
    """StopTargets of paired network target speeds and expert labels (NaN pairs left out)."""
    keep = np.isfinite(network) & np.isfinite(expert)
    network, expert = network[keep], expert[keep]
    stop = expert < STOP_SPEED_MPS
    creep = (network >= CREEP_BAND_MPS[0]) & (network <= CREEP_BAND_MPS[1])
    labels = expert[creep]
    stats = lambda values, f: round(float(f(values)), 3) if values.size else None  # noqa: E731
    return StopTargets(source, int(stop.sum()), stats(network[stop], np.mean), stats(network[stop], np.median),
                       stats(network[stop] >= STOP_SPEED_MPS, np.mean), int(creep.sum()),
                       stats(labels < STOP_SPEED_MPS, np.mean), stats(labels > DRIVE_MPS, np.mean),
                       stats((labels >= STOP_SPEED_MPS) & (labels <= DRIVE_MPS), np.mean))


def closed_loop_targets(runs: Sequence[Path], agent: str) -> tuple[np.ndarray, np.ndarray]:
    """Every step's (network target speed, expert label) of `agent`'s episodes with telemetry."""
    from msfsu_evaluation.closed_loop.runs import merge

    network, expert = [], []
    for (_, _), record in sorted(merge(runs, {agent}).items()):
        telemetry = record.telemetry()
        if telemetry is not None:
            network.append(telemetry.column("action_target_speed_mps"))
            expert.append(telemetry.column("expert_target_speed_mps"))
    if not network:
        return np.zeros(0), np.zeros(0)
    return np.concatenate(network), np.concatenate(expert)


# ----- open loop -----
def bootstrap_ratio(hits: np.ndarray, totals: np.ndarray, seed: int = 0) -> tuple[float, float] | None:
    """95 % bootstrap interval of sum(hits) / sum(totals) over frames (resampled with replacement)."""
    if totals.sum() == 0:
        return None
    rng = np.random.default_rng(seed)
    picks = rng.integers(0, len(totals), (BOOTSTRAP, len(totals)))
    ratios = hits[picks].sum(axis=1) / np.maximum(totals[picks].sum(axis=1), 1)
    return round(float(np.percentile(ratios, 2.5)), 4), round(float(np.percentile(ratios, 97.5)), 4)


def open_loop(network: str, checkpoint: Path, backend: str, precision: str, bags: Sequence[Path], cache: Path
              ) -> tuple[list[BandRecall], np.ndarray, np.ndarray]:
    """Band recalls of one network on the bags' frames (none without segmentation), and every frame's (network target,
    expert label)."""
    from msfsu_common.road_option import RoadOption
    from msfsu_common.semantic_classes import SemanticClass
    from msfsu_evaluation.deploy.scoring import load_held_out
    from msfsu_perception.bag_topics import BagTopics
    from msfsu_perception.deploy_files import cached_inputs
    from msfsu_perception.inference import DrivingModel

    model = DrivingModel.from_checkpoint(checkpoint, backend=backend, precision=precision)
    preprocess = model.preprocess
    # the ground truth's depth whether or not the network takes depth (SU does not): the distance bands need it
    held_out = load_held_out(bags, BagTopics(), dataclasses.replace(preprocess, use_depth=True), cache)
    inputs = np.empty((preprocess.channels, preprocess.input_height, preprocess.input_width), np.float32)
    hits = {band: [] for band in BANDS_M}
    totals = {band: [] for band in BANDS_M}
    targets, labels = [], []
    for bag in held_out:
        truth = bag.truth
        if truth.cache.depth is None:
            raise ValueError(f"{bag.path}: recall by distance needs depth")
        for index in bag.indices:
            row = truth.rows[index]
            depth = truth.cache.depth[row]
            cached_inputs(truth.cache.rgb[row], depth if preprocess.use_depth else None, inputs)
            prediction = model.predict(inputs, RoadOption(int(truth.command[index])))
            targets.append(prediction.target_speed)
            labels.append(float(truth.target_speed[index]))
            if prediction.class_ids is None:
                continue  # no segmentation (MSF): its target speeds only
            wanted = truth.cache.class_ids[row] == SemanticClass.VEHICLE_OR_PEDESTRIAN
            metres = np.asarray(depth, np.float32)[0] * preprocess.max_depth_m
            found = prediction.class_ids == SemanticClass.VEHICLE_OR_PEDESTRIAN
            for low, high in BANDS_M:
                band = wanted & (metres >= low) & (metres < high)
                totals[(low, high)].append(int(band.sum()))
                hits[(low, high)].append(int((band & found).sum()))
    recalls = []
    for band in BANDS_M if model.has_segmentation else ():
        h, t = np.array(hits[band]), np.array(totals[band])
        recalls.append(BandRecall(network, f"{band[0]:.0f}-{band[1]:.0f} m", int(t.sum()),
                                  round(float(h.sum() / t.sum()), 4) if t.sum() else None, bootstrap_ratio(h, t)))
    return recalls, np.array(targets), np.array(labels)


# ----- the page -----
def _percent(value: float | None) -> str:
    return "-" if value is None or (isinstance(value, float) and math.isnan(value)) else f"{100 * value:.0f} %"


def _number(value: float | None, digits: int = 2) -> str:
    return "-" if value is None or (isinstance(value, float) and math.isnan(value)) else f"{value:.{digits}f}"


def render(study: dict) -> str:
    lines = ["# Why the car does not stop for what it sees", "",
             f"Generated by `{study['command']}` (msfsu_evaluation/stopping_study.py says how each experiment can "
             "fail).", ""]
    if study.get("collisions") is not None:
        rows = [Collision(**row) for row in study["collisions"]]
        crept = sum(row.crept for row in rows)
        lines += ["## 1. Pedestrian collisions, closed loop", "",
                  f"Runs: {', '.join(study['runs'])}; agent {study['agent']}. {len(rows)} pedestrian collisions with "
                  f"telemetry ({study['collisions_without_telemetry']} without). Over the last {WINDOW_S:.0f} s of "
                  "each: the share of steps the nearest pedestrian ahead was in the camera's view and in the network's "
                  "crop, when it first entered the crop, its largest height in input pixels and the share of its box "
                  "the depth image showed; the network's mean target speed beside the expert's in the same state and "
                  f"the share of steps the expert asked to stop (< {STOP_SPEED_MPS} m/s); the lowest speed; crept: the "
                  f"car had slowed below {CREEP_MPS} m/s in its last {CREEP_LOOKBACK_S:g} s and from then still moved "
                  f"{CREEP_MOVED_M:g} m or more into the pedestrian.", "",
                  f"Crept: {crept} of {len(rows)}.", "",
                  "| agent | scenario / route | hit | in view | in crop | first in crop, s before | max px high | "
                  "visible | target m/s network / expert | expert stops | min speed | crept |",
                  "|" + " --- |" * 12]
        for row in rows:
            lines.append(f"| {row.agent} | {row.route} | {row.actor or '-'} | {_percent(row.in_view_share)} | "
                         f"{_percent(row.in_crop_share)} | {_number(row.first_in_crop_s, 1)} | "
                         f"{row.max_height_px:.0f} | {_percent(row.mean_visible)} | "
                         f"{_number(row.network_target_mps)} / {_number(row.expert_target_mps)} | "
                         f"{_percent(row.expert_stop_share)} | {row.min_speed_mps:.2f} | {'yes' if row.crept else 'no'} |")
        lines.append("")
    if study.get("recall"):
        lines += ["## 2. Recall of vehicle_or_pedestrian by distance, held-out bags", "",
                  f"Bags: {', '.join(study['bags'])} ({study['frames']} frames). Of the ground truth's "
                  "vehicle_or_pedestrian pixels at the network's input size, by the ground truth's depth: the share the "
                  "network labels so (95 % bootstrap interval over frames). Vehicles and pedestrians are one class.", "",
                  "| network | distance | ground-truth pixels | recall (95 % CI) |", "| --- | --- | --- | --- |"]
        for row in (BandRecall(**{**item, "ci95": tuple(item["ci95"]) if item["ci95"] else None})
                    for item in study["recall"]):
            interval = f" ({100 * row.ci95[0]:.0f}-{100 * row.ci95[1]:.0f})" if row.ci95 else ""
            lines.append(f"| {row.network} | {row.band} | {row.pixels} | {_percent(row.recall)}{interval} |")
        lines.append("")
    if study.get("stop_targets"):
        lines += ["## 3. The network's target speed where the expert stops", "",
                  f"Frames whose expert label is below the stop speed ({STOP_SPEED_MPS} m/s): the network's mean and "
                  f"median target and the share that keeps the car moving. Frames where the network asks for a creep "
                  f"({CREEP_BAND_MPS[0]}-{CREEP_BAND_MPS[1]} m/s): the expert's labels there, below the stop speed, "
                  f"above {DRIVE_MPS} m/s, or in between. Stops and drives with little in between: the creep is the mean "
                  "of a two-mode label; labels in between: the expert creeps too.", "",
                  "| source | expert-stop frames | network target mean / median | moving | creep frames | expert: stop / "
                  "drive / between |", "|" + " --- |" * 6]
        for row in (StopTargets(**item) for item in study["stop_targets"]):
            lines.append(f"| {row.source} | {row.stop_frames} | {_number(row.target_mean)} / "
                         f"{_number(row.target_median)} | {_percent(row.above_stop_share)} | {row.creep_frames} | "
                         f"{_percent(row.creep_expert_stop_share)} / {_percent(row.creep_expert_drive_share)} / "
                         f"{_percent(row.creep_expert_between_share)} |")
        lines.append("")
    if study.get("figure"):
        lines += [f"![the network's target speed against the expert's label]({study['figure']})", ""]
    return "\n".join(lines)


def plot(pairs: dict[str, tuple[np.ndarray, np.ndarray]], path: Path) -> str:
    """Histograms of the network's target where the expert stops, one panel per source."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    figure, axes = plt.subplots(1, len(pairs), figsize=(5 * len(pairs), 3.5), squeeze=False)
    for axis, (source, (network, expert)) in zip(axes[0], pairs.items()):
        keep = np.isfinite(network) & np.isfinite(expert) & (expert < STOP_SPEED_MPS)
        axis.hist(network[keep], bins=np.arange(-0.5, 8.6, 0.25), color="tab:blue")
        axis.axvline(STOP_SPEED_MPS, color="tab:red", linestyle="--", label=f"stop speed {STOP_SPEED_MPS} m/s")
        axis.set_title(source, fontsize=9)
        axis.set_xlabel("network target speed, m/s (expert label < stop speed)")
        axis.set_ylabel("frames")
        axis.legend(fontsize=8)
    figure.tight_layout()
    figure.savefig(path, dpi=110)
    plt.close(figure)
    return path.name


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m msfsu_evaluation.stopping_study", description=__doc__.splitlines()[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter, epilog=__doc__)
    parser.add_argument("--bags", nargs="+", default=[], help="held-out bags (globs) for recall and open-loop targets")
    parser.add_argument("--network", action="append", default=[], metavar="NAME=CHECKPOINT[:BACKEND/PRECISION]")
    parser.add_argument("--runs", nargs="+", type=Path, default=[], help="benchmark run directories with telemetry")
    parser.add_argument("--agent", help="the agent of --runs")
    parser.add_argument("--cache", type=Path, default=Path("runs/cache/stopping_study"))
    parser.add_argument("--out", type=Path)
    parser.add_argument("--render", type=Path, metavar="DIR", help="write DIR's page again from its study.json")
    options = parser.parse_args(argv)
    if options.render:
        study = json.loads((options.render / RECORD).read_text())
        (options.render / PAGE).write_text(render(study))
        return 0
    if options.out is None or (options.runs and not options.agent) or not (options.runs or options.bags):
        parser.error("give --out and --bags/--network and/or --runs with --agent")
    from glob import glob

    from msfsu_evaluation.closed_loop.runs import relative
    from msfsu_evaluation.lateral_study import parse_network

    bags = sorted(Path(path) for pattern in options.bags for path in glob(pattern))
    if options.bags and not bags:
        print(f"stopping_study: no bag matches {options.bags}", file=sys.stderr)
        return 2
    study: dict = {"command": "python -m msfsu_evaluation.stopping_study " + " ".join(argv or sys.argv[1:])}
    pairs: dict[str, tuple[np.ndarray, np.ndarray]] = {}
    stop_rows: list[StopTargets] = []
    if options.runs:
        rows, missing = collisions(options.runs, options.agent)
        study.update(runs=[relative(run) for run in options.runs], agent=options.agent,
                     collisions=[asdict(row) for row in rows], collisions_without_telemetry=missing)
        network, expert = closed_loop_targets(options.runs, options.agent)
        source = f"closed loop: {options.agent}"
        pairs[source] = (network, expert)
        stop_rows.append(stop_targets(network, expert, source))
    if bags:
        recalls = []
        for item in options.network:
            name, checkpoint, backend, precision = parse_network(item)
            band_recalls, network, expert = open_loop(name, checkpoint, backend, precision, bags, options.cache)
            recalls += band_recalls
            source = f"open loop: {name}"
            pairs[source] = (network, expert)
            stop_rows.append(stop_targets(network, expert, source))
            study["frames"] = int(len(network))
        study.update(bags=[bag.name for bag in bags], recall=[asdict(row) for row in recalls])
    study["stop_targets"] = [asdict(row) for row in stop_rows]
    options.out.mkdir(parents=True, exist_ok=True)
    if pairs:
        study["figure"] = plot(pairs, options.out / "stop_targets.png")
    (options.out / RECORD).write_text(json.dumps(study, indent=2) + "\n")
    (options.out / PAGE).write_text(render(study))
    print((options.out / PAGE).read_text())
    return 0


if __name__ == "__main__":
    sys.exit(main())
