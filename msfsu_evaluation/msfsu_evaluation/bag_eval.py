"""msfsu-eval-bag: open-loop evaluation of a checkpoint on a rosbag2 bag, through the real node graph.

    msfsu-eval-bag BAG --checkpoint C --out DIR [--rate R] [--remap /bag/topic:=/graph/topic ...]

The bag is played through bag_player -> perception -> control (bringup `replay` profile, one process
per node) while a recorder keeps the outputs; those are matched by header stamp with the bag's
ground truth (expert DrivingAction, semantic class ids). Writes report.json, report.md, frames.csv,
PNG figures, the recording and the nodes' log (replay.log) into DIR.

Bags recorded elsewhere (CARLA bridge: bgra8 RGB, 32FC1 depth, other topic names) are played with
remaps onto the graph's inputs; the ground truth is read from the same bag topics. Semantic ground
truth must be mono8 class ids (0..4); without it segmentation is not scored. Frames recorded while
noise was injected are left out, as in training.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Mapping, Sequence
from dataclasses import asdict
from pathlib import Path
from typing import Any

from msfsu_common import topics
from msfsu_common.bag_io import CAMERA, METADATA_PREFIX, SOURCE_BAG, open_bag, read_bag_metadata
from msfsu_common.camera_geometry import FrontCamera
from msfsu_evaluation.evaluation import Evaluation, evaluate
from msfsu_evaluation.graph_run import ReplayError, ReplayRequest, run_replay
from msfsu_evaluation.ground_truth import load_ground_truth, topic_message_counts
from msfsu_evaluation.plots import plot_actions, plot_confusion, plot_overlays
from msfsu_evaluation.recording import read_outputs
from msfsu_evaluation.open_loop_report import (camera_sentence, report_dict, summary_markdown, write_frames_csv,
                                               write_report)
from msfsu_evaluation.usage import UsageError, parse_remap_pairs
from msfsu_perception.bag_topics import BagTopics
from msfsu_perception.checkpoint import CheckpointError, load_checkpoint
from msfsu_perception.frame_cache import CacheSpaceError

# Graph inputs a remap may target, and the BagTopics field the ground truth reads them from.
GRAPH_INPUTS = {topics.RGB: "rgb", topics.DEPTH: "depth", topics.NAVIGATION_COMMAND: "navigation_command"}
RECORDING_DIR = "recording"


def parse_remaps(items: Sequence[str], bag_topics: set[str]) -> dict[str, str]:
    """["/bag/topic:=/graph/topic", ...] -> {bag topic: graph input}."""
    return dict(parse_remap_pairs(items, bag_topics, GRAPH_INPUTS, "a graph input", "/graph/topic"))


def ground_truth_topics(remap: dict[str, str], options: argparse.Namespace) -> BagTopics:
    """Inputs are read where the player takes them from; ground-truth-only topics come from the options."""
    bag_topic_of = {target: source for source, target in remap.items()}
    inputs = {field: bag_topic_of.get(graph_topic, graph_topic) for graph_topic, field in GRAPH_INPUTS.items()}
    return BagTopics(**inputs, expert_action=options.expert_topic, semantic_ids=options.semantic_topic,
                     noise_injection=options.noise_topic)


def build_parser() -> argparse.ArgumentParser:
    defaults = BagTopics()
    parser = argparse.ArgumentParser(prog="msfsu-eval-bag", description=__doc__.split("\n")[0],
                                     formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    parser.add_argument("bag", type=Path, help="rosbag2 directory (MCAP or sqlite3)")
    parser.add_argument("--checkpoint", type=Path, required=True, help="MSFSU checkpoint (.pt)")
    parser.add_argument("--out", type=Path, required=True, help="report directory (created)")
    parser.add_argument("--rate", type=float, default=1.0,
                        help="playback speed; below 1 gives a slow network time for every frame")
    parser.add_argument("--remap", action="append", default=[], metavar="/BAG/TOPIC:=/GRAPH/TOPIC",
                        help=f"play a bag topic as a graph input ({', '.join(GRAPH_INPUTS)}); repeatable")
    truth = parser.add_argument_group("ground-truth topics of the bag")
    truth.add_argument("--expert-topic", default=defaults.expert_action, help="expert DrivingAction")
    truth.add_argument("--semantic-topic", default=defaults.semantic_ids, help="mono8 class ids (optional)")
    truth.add_argument("--noise-topic", default=defaults.noise_injection, help="std_msgs/Bool noise injection flag")
    parser.add_argument("--cache-dir", type=Path, default=Path("data/cache"),
                        help="decoded ground-truth cache (shared with msfsu-train)")
    parser.add_argument("--overlays", type=int, default=4, help="frames shown in segmentation_overlays.png")
    parser.add_argument("--no-aeb", action="store_true",
                        help="replay without the emergency brake between perception and control (the replay "
                             "profile's default has it; the report says what it did)")
    return parser


def bag_camera(bag: Path, metadata: Mapping[str, str]) -> FrontCamera | None:
    """The camera the bag's frames were taken with (its `metadata`'s CAMERA: msfsu-collect and msfsu-import-carla
    write it), which the emergency brake places pixels with; None for a bag that names none (the simulator's is
    assumed). UsageError for one that names something else."""
    if CAMERA not in metadata:
        return None
    try:
        return FrontCamera.from_json(metadata[CAMERA])
    except ValueError as error:
        raise UsageError(f"{bag}: metadata {METADATA_PREFIX}{CAMERA}: {error}") from None


def describe_camera(camera: FrontCamera | None, metadata: Mapping[str, str]) -> str:
    """The line msfsu-eval-bag prints of the brake's camera (with a hint for an import that predates it)."""
    if camera is not None:
        return camera_sentence(asdict(camera))
    return camera_sentence("simulator") + (" (an import of a CARLA recording from before the import wrote its "
                                           "camera: import it again for the brake to see with that camera)"
                                           if SOURCE_BAG in metadata else "")


def _validate(options: argparse.Namespace) -> None:
    if options.rate <= 0:
        raise UsageError(f"--rate must be positive, got {options.rate}")
    if options.overlays < 1:
        raise UsageError(f"--overlays must be at least 1, got {options.overlays}")
    if (options.out / RECORDING_DIR).exists():
        raise UsageError(f"{options.out} already holds a run; choose a new --out")


def write_outputs(evaluation: Evaluation, run_info: dict[str, Any], class_names: tuple[str, ...], out: Path) -> dict:
    """Figures, report.json, report.md and frames.csv into `out`; returns the report."""
    figures = [plot_actions(evaluation.series, out / "actions.png")]
    if evaluation.confusion is not None:
        figures.append(plot_confusion(evaluation.confusion, class_names, out / "confusion_matrix.png"))
        figures.append(plot_overlays(evaluation.overlays, class_names, out / "segmentation_overlays.png"))
    report = report_dict(evaluation, run_info, class_names)
    write_report(report, figures, out)
    write_frames_csv(evaluation.series, out / "frames.csv")
    return report


def run(options: argparse.Namespace) -> None:
    _validate(options)
    open_bag(options.bag).close()  # BagError: no bag; a damaged one is recovered, with a warning
    checkpoint = load_checkpoint(options.checkpoint)
    remap = parse_remaps(options.remap, set(topic_message_counts(options.bag)))
    bag_topics = ground_truth_topics(remap, options)
    metadata = read_bag_metadata(options.bag)
    camera = None if options.no_aeb else bag_camera(options.bag, metadata)
    options.out.mkdir(parents=True, exist_ok=True)

    print(f"[1/4] ground truth from {options.bag} (cache {options.cache_dir})", flush=True)
    truth = load_ground_truth(options.bag, bag_topics, checkpoint.preprocess, options.cache_dir)
    print(f"      {len(truth)} of {truth.camera_frames} camera frames have ground truth", flush=True)
    if not truth.has_labels:
        print(f"      no {bag_topics.semantic_ids} in the bag: segmentation is not scored", flush=True)

    recording, log = options.out / RECORDING_DIR, options.out / "replay.log"
    print(f"[2/4] replaying through the node graph at rate {options.rate} (node logs: {log})", flush=True)
    if not options.no_aeb:
        print(f"      {describe_camera(camera, metadata)}", flush=True)
    played = [bag_topics.rgb, bag_topics.depth, bag_topics.navigation_command]
    bag_topic_names = set(topic_message_counts(options.bag))
    odometry = next((bag for bag, graph in remap.items() if graph == topics.ODOMETRY), topics.ODOMETRY)
    if odometry in bag_topic_names:  # the car's speed: for the control and the emergency brake's time to collision
        played.append(odometry)
    run_replay(ReplayRequest(bag=options.bag, checkpoint=options.checkpoint, recording=recording, log=log,
                             rate=options.rate, remap=remap, play_topics=played, aeb=not options.no_aeb,
                             crop_top_fraction=checkpoint.preprocess.crop_top_fraction, camera=camera))

    print("[3/4] comparing outputs with the ground truth", flush=True)
    evaluation = evaluate(truth, read_outputs(recording), recording, len(checkpoint.class_names), options.overlays)

    print(f"[4/4] writing the report into {options.out}", flush=True)
    run_info = {
        "bag": str(options.bag), "checkpoint": str(options.checkpoint), "rate": options.rate, "remap": remap,
        "ground_truth_topics": asdict(bag_topics), "network": checkpoint.model.config.to_dict(),
        "aeb_camera": None if options.no_aeb else asdict(camera) if camera else "simulator",
    }
    report = write_outputs(evaluation, run_info, checkpoint.class_names, options.out)
    print("\n" + "\n".join(summary_markdown(report)), flush=True)


def main(argv: Sequence[str] | None = None) -> int:
    options = build_parser().parse_args(argv)
    try:
        run(options)
    except UsageError as error:
        print(f"msfsu-eval-bag: {error}", file=sys.stderr)
        return 2
    except (CheckpointError, ReplayError, CacheSpaceError, ValueError, FileNotFoundError) as error:
        print(f"msfsu-eval-bag: {error}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
