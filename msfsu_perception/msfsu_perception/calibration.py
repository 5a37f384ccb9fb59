"""Calibration frames for int8 post-training quantisation, stored next to the checkpoint.

`<checkpoint>.calibration.npz` holds preprocessed frames from training bags in the frame cache's
compact layout (rgb uint8, depth float16, command branch index); an int8 model is quantised from it
on first use and cached under its hash (deploy_files.DeployFiles). Build it once per checkpoint (msfsu-gate's
first step does it when the frames are missing or older than the checkpoint):

    msfsu-calibrate runs/cpu/best.pt --bags 'data/bags/*'
"""

from __future__ import annotations

import argparse
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from msfsu_common.road_option import RoadOption, branch_indices
from msfsu_perception.bag_topics import BagTopics
from msfsu_perception.bag_paths import expand_bag_paths, split_bags
from msfsu_perception.deploy_files import CalibrationSet, calibration_path
from msfsu_perception.frame_cache import CacheSpaceError, CacheSpec, open_cache
from msfsu_perception.preprocessing import PreprocessConfig

DEFAULT_FRAMES = 128  # NNCF's and ORT's min/max statistics settle well below this; quantising stays < 1 min


def _spread(count: int, frames: int) -> np.ndarray:
    """`frames` of `count` indices spread over the whole range (not the first seconds of one bag)."""
    return np.unique(np.linspace(0, count - 1, min(frames, count)).round().astype(np.int64))


def command_quotas(available: dict[int, int], frames: int) -> dict[int, int]:
    """Frames per command: an equal share each, a command with fewer frames gives the rest to the others."""
    quotas = {command: 0 for command in available}
    left, open_commands = frames, sorted(command for command, count in available.items() if count > 0)
    while left > 0 and open_commands:
        share, extra = divmod(left, len(open_commands))
        for position, command in enumerate(list(open_commands)):
            take = min(share + (position < extra), available[command] - quotas[command])
            quotas[command] += take
            left -= take
            if quotas[command] == available[command]:
                open_commands.remove(command)
    return quotas


def stratified_rows(rows: np.ndarray, commands: np.ndarray, frames: int) -> np.ndarray:
    """`frames` of `rows` (with their navigation commands), balanced over the commands and spread over the
    recording within each; sorted.

    Junction frames (LEFT / RIGHT / STRAIGHT) are a few percent of driving: evenly spaced frames would
    calibrate int8 almost only on lane following.
    """
    if len(rows) == 0:
        raise ValueError("no usable frames to calibrate on")
    by_command = {int(command): rows[commands == command] for command in np.unique(commands)}
    quotas = command_quotas({command: len(members) for command, members in by_command.items()}, frames)
    chosen = [members[_spread(len(members), quotas[command])] for command, members in by_command.items()
              if quotas[command] > 0]
    return np.sort(np.concatenate(chosen))


def build_calibration_set(
    bags: Sequence[Path], preprocess: PreprocessConfig, path: Path, cache_root: Path, frames: int = DEFAULT_FRAMES,
    topics: BagTopics = BagTopics(),
) -> CalibrationSet:
    """Sample `frames` frames of `bags` (through the training frame cache), balanced over the commands, into `path`."""
    cache = open_cache(CacheSpec(tuple(bags), topics, preprocess, with_labels=False), cache_root)
    if len(cache.valid_rows) == 0:
        raise ValueError(f"no usable frames in {cache.directory}")
    rows = stratified_rows(cache.valid_rows, np.asarray(cache.command[cache.valid_rows]), frames)
    arrays = {"rgb": np.asarray(cache.rgb[rows]), "command_index": branch_indices(cache.command[rows])}
    if cache.depth is not None:
        arrays["depth"] = np.asarray(cache.depth[rows])
    path.parent.mkdir(parents=True, exist_ok=True)
    temporary = path.with_name(f".{path.name}.partial.npz")
    np.savez_compressed(temporary, **arrays)  # small enough to ship beside a checkpoint
    temporary.replace(path)
    return CalibrationSet.load(path)


def calibrate(checkpoint: Path, bags: Sequence[str | Path], cache_root: Path, frames: int = DEFAULT_FRAMES
              ) -> CalibrationSet:
    """`<checkpoint>.calibration.npz` from the training split of `bags` (paths or globs); ValueError without one."""
    from msfsu_perception.checkpoint import load_checkpoint

    if frames <= 0:
        raise ValueError(f"calibration frames must be positive, got {frames}")
    train_bags = split_bags(expand_bag_paths(bags))["train"]
    if not train_bags:
        raise ValueError("no bag with split 'train' among the calibration bags")
    preprocess = load_checkpoint(checkpoint).preprocess
    return build_calibration_set(train_bags, preprocess, calibration_path(checkpoint), cache_root, frames)


def is_current(checkpoint: Path) -> bool:
    """The checkpoint has calibration frames written after it (a retrained checkpoint needs new ones)."""
    path = calibration_path(checkpoint)
    return path.is_file() and path.stat().st_mtime > checkpoint.stat().st_mtime


def summary(calibration: CalibrationSet) -> str:
    """`<path>: N frames (LEFT n, ...)`."""
    commands = ", ".join(f"{option.name} {int(np.sum(calibration.command_index == option.branch_index))}"
                         for option in RoadOption)
    return f"{calibration.path}: {len(calibration)} frames ({commands})"


def main(argv: Sequence[str] | None = None) -> None:
    from msfsu_common.bag_io import BagError
    from msfsu_perception.checkpoint import CheckpointError

    parser = argparse.ArgumentParser(prog="python -m msfsu_perception.calibration",
                                     description="Write <checkpoint>.calibration.npz from training bags.")
    parser.add_argument("checkpoint", type=Path)
    parser.add_argument("--bags", nargs="+", required=True, help="bag dirs / globs; their 'train' split is used")
    parser.add_argument("--frames", type=int, default=DEFAULT_FRAMES)
    parser.add_argument("--cache-dir", type=Path, default=Path("data/cache"), help="decoded frame cache")
    args = parser.parse_args(argv)
    try:
        calibration = calibrate(args.checkpoint, args.bags, args.cache_dir, args.frames)
    except (CheckpointError, BagError, CacheSpaceError, ValueError) as error:
        raise SystemExit(f"msfsu-calibrate: {error}") from None
    print(f"wrote {summary(calibration)}")


if __name__ == "__main__":
    main()
