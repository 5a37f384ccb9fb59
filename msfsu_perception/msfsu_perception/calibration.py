"""Calibration frames for int8 post-training quantisation, stored next to the checkpoint.

`<checkpoint>.calibration.npz` holds preprocessed frames from training bags in the frame cache's
compact layout (rgb uint8, depth float16, command branch index); an int8 model is quantised from it
on first use and cached under its hash (deploy_files.DeployFiles). Build it once per checkpoint:

    python -m msfsu_perception.calibration runs/cpu/best.pt --bags 'data/bags/*'
"""

from __future__ import annotations

import argparse
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from msfsu_common.road_option import branch_indices
from msfsu_perception.bag_topics import BagTopics
from msfsu_perception.dataset import CacheSpec, FrameCache, expand_bag_paths, open_cache, split_bags
from msfsu_perception.deploy_files import CalibrationSet, calibration_path
from msfsu_perception.preprocessing import PreprocessConfig

DEFAULT_FRAMES = 128  # NNCF's and ORT's min/max statistics settle well below this; quantising stays < 1 min


def evenly_spaced_rows(cache: FrameCache, frames: int) -> np.ndarray:
    """Valid rows spread over the whole recording (not the first seconds of one bag)."""
    rows = cache.valid_rows
    if len(rows) == 0:
        raise ValueError(f"no usable frames in {cache.directory}")
    return rows[np.unique(np.linspace(0, len(rows) - 1, min(frames, len(rows))).round().astype(np.int64))]


def build_calibration_set(
    bags: Sequence[Path], preprocess: PreprocessConfig, path: Path, cache_root: Path, frames: int = DEFAULT_FRAMES,
    topics: BagTopics = BagTopics(),
) -> CalibrationSet:
    """Sample `frames` frames of `bags` (through the training frame cache) into `path`."""
    cache = open_cache(CacheSpec(tuple(bags), topics, preprocess, with_labels=False), cache_root)
    rows = evenly_spaced_rows(cache, frames)
    arrays = {"rgb": np.asarray(cache.rgb[rows]), "command_index": branch_indices(cache.command[rows])}
    if cache.depth is not None:
        arrays["depth"] = np.asarray(cache.depth[rows])
    path.parent.mkdir(parents=True, exist_ok=True)
    temporary = path.with_name(f".{path.name}.partial.npz")
    np.savez(temporary, **arrays)
    temporary.replace(path)
    return CalibrationSet.load(path)


def main(argv: Sequence[str] | None = None) -> None:
    from msfsu_perception.checkpoint import load_checkpoint

    parser = argparse.ArgumentParser(prog="python -m msfsu_perception.calibration",
                                     description="Write <checkpoint>.calibration.npz from training bags.")
    parser.add_argument("checkpoint", type=Path)
    parser.add_argument("--bags", nargs="+", required=True, help="bag dirs / globs; their 'train' split is used")
    parser.add_argument("--frames", type=int, default=DEFAULT_FRAMES)
    parser.add_argument("--cache-dir", type=Path, default=Path("data/cache"), help="decoded frame cache")
    args = parser.parse_args(argv)
    train_bags = split_bags(expand_bag_paths(args.bags))["train"]
    if not train_bags:
        raise SystemExit("no bag with split 'train' among --bags")
    preprocess = load_checkpoint(args.checkpoint).preprocess
    path = calibration_path(args.checkpoint)
    calibration = build_calibration_set(train_bags, preprocess, path, args.cache_dir, args.frames)
    print(f"wrote {path}: {len(calibration)} frames from {len(train_bags)} training bags")


if __name__ == "__main__":
    main()
