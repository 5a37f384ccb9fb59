"""`msfsu-dataset-report`: what a collected data set holds, per split, round and traffic level (issue #12).

    msfsu-dataset-report data/v2 --out docs/results/data      # writes data.json (the record) and data.md
    msfsu-dataset-report --record docs/results/data/data.json --out docs/results/data   # data.md from the record

One pass per bag over its small topics (no image is decoded): frames (one expert label per simulator step),
frames labelled below 1 m/s (stopping), frames the network drove (`topics.NETWORK_DRIVING`), noise-injected
frames (left out of training), frames per navigation command, what held the expert's label below its desired
speed (`topics.EXPERT_LIMITED_BY`: a vehicle, a pedestrian, a junction wait; bags collected before it was recorded
show "-"), and the bag's metadata (split, town, weather, traffic, round, driver). Episodes `msfsu-collect`
dropped (`dropped.jsonl`: an expert episode that crashed, with its reason) count as attempts, so the table gives the expert's crash rate per traffic level with a
Wilson 95 % interval. The bags are not committed; data.json is, and data.md is generated from it alone.
"""

from __future__ import annotations

import argparse
import bisect
import json
import sys
from collections import Counter
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path

from tqdm import tqdm

from msfsu_common import bag_io, topics
from msfsu_common.message_types import stamp_ns
from msfsu_common.road_option import RoadOption
from msfsu_evaluation.closed_loop.statistics import wilson_interval
from msfsu_sim.environment import STEP_S  # one frame per simulator step
from msfsu_sim.episode_recording import SLOW_MPS  # as msfsu-collect reports: a label below this is stopping

RECORD_FORMAT = 1
TRAFFIC_ORDER = ("empty", "regular", "dense")
_KNOWN_COMMANDS = frozenset(option.value for option in RoadOption)
HELD_BY = tuple(kind for kind in bag_io.EXPERT_LIMITS if kind != "free")  # the report's shares, in this order


@dataclass
class BagStats:
    name: str
    split: str
    town: str
    weather: str
    traffic: str
    round: int
    driver: str
    frames: int = 0  # expert labels
    slow_frames: int = 0  # labelled below SLOW_MPS
    network_frames: int = 0  # driven by the network
    noisy_frames: int = 0  # steering noise injected (not trained on)
    commands: dict[str, int] = field(default_factory=dict)  # RoadOption name -> labelled frames
    limited_by: dict[str, int] = field(default_factory=dict)  # bag_io.EXPERT_LIMITS -> frames ({}: not recorded)


def bag_stats(bag: Path) -> BagStats:
    """One bag's counts, from its small topics."""
    metadata = bag_io.read_bag_metadata(bag)
    stats = BagStats(bag.name, metadata.get(bag_io.SPLIT, "?"), metadata.get(bag_io.MAP, "?"),
                     metadata.get(bag_io.WEATHER, "?"), metadata.get(bag_io.TRAFFIC, "?"),
                     int(metadata.get(bag_io.ROUND, 0)), metadata.get(bag_io.DRIVER, bag_io.EXPERT_DRIVER))
    store = bag_io.msfsu_typestore()
    wanted = {topics.EXPERT_ACTION, topics.NAVIGATION_COMMAND, topics.NETWORK_DRIVING, topics.NOISE_INJECTION,
              topics.EXPERT_LIMITED_BY}
    limits: Counter[str] = Counter()
    labels: list[tuple[int, int, float]] = []  # (stamp, log time, target speed)
    commands: list[tuple[int, int]] = []  # (stamp, RoadOption value)
    flags: dict[str, list[tuple[int, bool]]] = {topics.NETWORK_DRIVING: [], topics.NOISE_INJECTION: []}  # (log, value)
    with bag_io.open_bag(bag) as reader:
        for connection, log_ns, raw in reader.messages([c for c in reader.connections if c.topic in wanted]):
            message = store.deserialize_cdr(raw, connection.msgtype)
            if connection.topic == topics.EXPERT_ACTION:
                labels.append((stamp_ns(message.header), log_ns, float(message.target_speed)))
            elif connection.topic == topics.NAVIGATION_COMMAND:
                commands.append((stamp_ns(message.header), int(message.command)))
            elif connection.topic == topics.EXPERT_LIMITED_BY:
                limits[str(message.data)] += 1  # one per labelled frame, written with its label
            else:
                flags[connection.topic].append((log_ns, bool(message.data)))

    def latest(pairs: list[tuple[int, object]], time: int) -> object:
        """The value of the last pair at or before `time` (the dataset's rule: a flag holds until the next)."""
        position = bisect.bisect_right(pairs, (time, True), key=lambda pair: (pair[0], True))
        return pairs[position - 1][1] if position else None

    commands.sort()
    for pairs in flags.values():
        pairs.sort(key=lambda pair: pair[0])
    per_command: Counter[str] = Counter()
    for stamp, log_ns, speed in labels:
        value = latest(commands, stamp)
        per_command[RoadOption(value).name if value in _KNOWN_COMMANDS else "none"] += 1
        stats.slow_frames += speed < SLOW_MPS
        stats.network_frames += bool(latest(flags[topics.NETWORK_DRIVING], log_ns))
        stats.noisy_frames += bool(latest(flags[topics.NOISE_INJECTION], log_ns))
    stats.frames = len(labels)
    stats.commands = dict(sorted(per_command.items()))
    stats.limited_by = dict(sorted(limits.items()))
    return stats


def find_bags(root: Path) -> list[Path]:
    """Every finished bag below `root` (unfinished ones in .partial/ are not part of the data set)."""
    return sorted(path.parent for path in root.rglob(bag_io.METADATA_FILE) if ".partial" not in path.parts)


def dropped_episodes(root: Path) -> list[dict]:
    """msfsu-collect's dropped.jsonl lines of every dataset root below `root`."""
    rows = []
    for log in sorted(root.rglob("dropped.jsonl")):
        for line in log.read_text().splitlines():
            entry = json.loads(line)
            episode = entry["episode"]
            rows.append({"split": episode["split"], "town": episode["town"], "weather": episode["weather"],
                         "traffic": episode["traffic"], "round": episode.get("round", 0), "reason": entry["reason"],
                         "steps": entry["steps"]})
    return rows


def build_record(root: Path) -> dict:
    bags = find_bags(root)
    rows = [asdict(bag_stats(bag)) for bag in tqdm(bags, desc="bags", unit="bag", leave=False)]
    return {"format": RECORD_FORMAT, "root": str(root), "bags": rows, "dropped": dropped_episodes(root)}


def _share(part: int, whole: int) -> str:
    return f"{part} ({100 * part / whole:.1f} %)" if whole else "0"


def _limits(bags: list[dict]) -> str:
    """Shares of the frames whose label a vehicle / a pedestrian / a junction wait held down, over the bags that
    recorded it ("-" if none did)."""
    recorded = [b for b in bags if b.get("limited_by")]
    frames = sum(sum(b["limited_by"].values()) for b in recorded)
    if not frames:
        return "-"
    shares = [100 * sum(b["limited_by"].get(kind, 0) for b in recorded) / frames for kind in HELD_BY]
    partial = "" if len(recorded) == len(bags) else f" ({len(recorded)} of {len(bags)} bags)"
    return " / ".join(f"{share:.1f}" for share in shares) + " %" + partial


def markdown(record: dict, command: str) -> str:
    bags, dropped = record["bags"], record["dropped"]
    groups = sorted({(b["split"], b["round"]) for b in bags} | {(d["split"], d["round"]) for d in dropped})
    lines = ["# The collected data set", "", f"Generated by `{command}` from `data.json` (the bags themselves are "
             "not committed). One frame per simulator step (10 Hz); the expert labels every frame, also the ones a "
             "network drove. Kept: episodes whose bag was written; an expert-only episode that ended in a collision "
             "or off the road is dropped (not trained on), so kept / attempted is the expert's clean-driving rate "
             "(Wilson 95 % interval). Noise: frames with injected steering noise, left out of training.", ""]
    for split, round_index in groups:
        mine = [b for b in bags if b["split"] == split and b["round"] == round_index]
        lost = [d for d in dropped if d["split"] == split and d["round"] == round_index]
        drivers = sorted({b["driver"] for b in mine})
        lines += [f"## {split}, round {round_index} (driver: {', '.join(drivers) or '-'})", "",
                  "| traffic | kept / attempted episodes (95 % CI) | crashes dropped | frames | hours | label < 1 m/s | "
                  f"driven by the network | noise | label held by {' / '.join(HELD_BY)} | "
                  "LEFT / RIGHT / STRAIGHT / LANE_FOLLOW frames |",
                  "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |"]
        levels = sorted({b["traffic"] for b in mine} | {d["traffic"] for d in lost},
                        key=lambda level: (TRAFFIC_ORDER.index(level) if level in TRAFFIC_ORDER else 9, level))
        for level in [*levels, "all"]:
            at = [b for b in mine if level in ("all", b["traffic"])]
            gone = [d for d in lost if level in ("all", d["traffic"])]
            attempts = len(at) + len(gone)
            frames = sum(b["frames"] for b in at)
            commands: Counter[str] = Counter()
            for b in at:
                commands.update(b["commands"])
            interval = wilson_interval(len(at), attempts) if attempts else None
            kept = (f"{len(at)}/{attempts} ({100 * len(at) / attempts:.0f} %; {100 * interval.low:.0f}-"
                    f"{100 * interval.high:.0f})" if interval else "0/0")
            crashes = Counter(d["reason"] for d in gone if d["reason"] in bag_io.CRASH_ENDS)
            name = f"**{level}**" if level == "all" else level
            lines.append(
                f"| {name} | {kept} | {', '.join(f'{n} {reason}' for reason, n in sorted(crashes.items())) or '0'} | "
                f"{frames} | {frames * STEP_S / 3600:.2f} | {_share(sum(b['slow_frames'] for b in at), frames)} | "
                f"{_share(sum(b['network_frames'] for b in at), frames)} | "
                f"{_share(sum(b['noisy_frames'] for b in at), frames)} | {_limits(at)} | "
                f"{' / '.join(str(commands.get(option.name, 0)) for option in RoadOption)} |")
        towns = Counter(b["town"] for b in mine)
        weathers = Counter(b["weather"] for b in mine)
        lines += ["", f"Towns: {', '.join(f'{t} {n}' for t, n in sorted(towns.items()))}; weathers: "
                  f"{', '.join(f'{w} {n}' for w, n in sorted(weathers.items()))} (kept bags).", ""]
    return "\n".join(lines)


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="msfsu-dataset-report", description=__doc__.splitlines()[0])
    parser.add_argument("root", type=Path, nargs="?", help="dataset root (msfsu-collect --output)")
    parser.add_argument("--record", type=Path, help="regenerate data.md from this data.json instead of the bags")
    parser.add_argument("--out", type=Path, required=True, help="directory for data.json and data.md")
    args = parser.parse_args(argv)
    if (args.root is None) == (args.record is None):
        parser.error("give a dataset root or --record, not both")
    if args.record is not None:
        record = json.loads(args.record.read_text())
    else:
        if not args.root.is_dir() or not find_bags(args.root):
            print(f"msfsu-dataset-report: {args.root}: no bag below it", file=sys.stderr)
            return 1
        record = build_record(args.root)
        args.out.mkdir(parents=True, exist_ok=True)
        (args.out / "data.json").write_text(json.dumps(record, indent=1) + "\n")
    command = f"msfsu-dataset-report --record {args.out / 'data.json'} --out {args.out}"
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "data.md").write_text(markdown(record, command) + "\n")
    print(f"wrote {args.out / 'data.md'}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
