"""Self-describing checkpoints that load with `torch.load(weights_only=True)` (no arbitrary pickle).

A file holds only tensors, dicts, lists, strings and numbers: the state dict, the architecture
(MSFSUConfig), the preprocessing constants (PreprocessConfig), the speed normalisation, the class
names and the command order, free-form training metadata and, in `last.pt`, the training state
(optimizer, scheduler, RNG) needed to resume. Anything unexpected raises CheckpointError.
"""

from __future__ import annotations

import argparse
import os
import sys
from collections.abc import Mapping
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import torch

from msfsu_common.road_option import RoadOption
from msfsu_common.semantic_classes import CLASS_NAMES
from msfsu_perception.model import MSFSUConfig, MSFSUNet, build_model
from msfsu_perception.preprocessing import PreprocessConfig

FORMAT = "msfsu-checkpoint"
FORMAT_VERSION = 1
COMMAND_ORDER = tuple(option.name for option in sorted(RoadOption, key=lambda option: option.branch_index))
DEFAULT_SPEED_SCALE_MPS = 10.0  # speed_normalised = target_speed [m/s] / speed_scale


class CheckpointError(Exception):
    """The file is missing, unreadable or does not describe a network this code can build."""


@dataclass(frozen=True)
class LoadedCheckpoint:
    model: MSFSUNet  # fp32, in eval mode
    preprocess: PreprocessConfig
    speed_scale: float
    class_names: tuple[str, ...]
    training: dict[str, Any] = field(default_factory=dict)  # metadata: epoch, val loss, data, ...
    training_state: dict[str, Any] | None = None  # optimizer/scheduler/RNG, only when asked for


def check_compatible(model_config: MSFSUConfig, preprocess: PreprocessConfig) -> None:
    """The preprocessing must produce what the network takes."""
    expected = (model_config.in_channels, model_config.input_height, model_config.input_width)
    produced = (preprocess.channels, preprocess.input_height, preprocess.input_width)
    if expected != produced:
        raise CheckpointError(f"preprocessing produces (C, H, W) = {produced}, the network takes {expected}")


def save_checkpoint(
    path: Path | str,
    model: MSFSUNet,
    preprocess: PreprocessConfig,
    speed_scale: float = DEFAULT_SPEED_SCALE_MPS,
    training: Mapping[str, Any] | None = None,
    training_state: Mapping[str, Any] | None = None,
    half: bool = False,
) -> None:
    """Write atomically (temp file + rename), so a crash never leaves a torn best.pt/last.pt.

    half=True stores floating-point weights as fp16 (half the size); loading restores fp32.
    """
    check_compatible(model.config, preprocess)
    storage_dtype = torch.float16 if half else torch.float32
    state_dict = {
        name: tensor.detach().to("cpu", storage_dtype if tensor.is_floating_point() else tensor.dtype).contiguous()
        for name, tensor in model.state_dict().items()
    }
    payload: dict[str, Any] = {
        "format": FORMAT,
        "format_version": FORMAT_VERSION,
        "model_config": model.config.to_dict(),
        "preprocess_config": asdict(preprocess),
        "speed_scale_mps": float(speed_scale),
        "class_names": list(CLASS_NAMES),
        "command_order": list(COMMAND_ORDER),
        "storage_dtype": str(storage_dtype).removeprefix("torch."),
        "training": dict(training or {}),
        "state_dict": state_dict,
    }
    if training_state is not None:
        payload["training_state"] = dict(training_state)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    temporary = path.with_name(path.name + ".tmp")
    torch.save(payload, temporary)
    os.replace(temporary, path)


def _read_payload(path: Path) -> dict[str, Any]:
    if not path.is_file():
        raise CheckpointError(f"checkpoint {path} does not exist")
    try:
        payload = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as error:  # torch raises several unrelated types for a damaged file
        # its first sentence: torch's messages go on for lines (weights_only's history and advice)
        reason = (str(error).strip().splitlines() or [type(error).__name__])[0].split(". ")[0]
        raise CheckpointError(f"checkpoint {path} is corrupt or not a safe torch file: {reason}") from error
    if not isinstance(payload, dict) or payload.get("format") != FORMAT:
        raise CheckpointError(f"{path} is not an MSFSU checkpoint (no '{FORMAT}' marker)")
    if payload.get("format_version") != FORMAT_VERSION:
        raise CheckpointError(
            f"{path} has format version {payload.get('format_version')}, this code reads {FORMAT_VERSION}"
        )
    return payload


def _configs(payload: Mapping[str, Any], path: Path) -> tuple[MSFSUConfig, PreprocessConfig]:
    try:
        model_config = MSFSUConfig.from_dict(payload["model_config"])
        preprocess = PreprocessConfig(**payload["preprocess_config"])
    except (KeyError, TypeError, ValueError) as error:
        raise CheckpointError(f"{path} has an invalid configuration: {error}") from error
    check_compatible(model_config, preprocess)
    if tuple(payload.get("command_order", ())) != COMMAND_ORDER:
        raise CheckpointError(f"{path} orders its branches {payload.get('command_order')}, expected {COMMAND_ORDER}")
    if len(payload.get("class_names", ())) != model_config.num_classes:
        raise CheckpointError(f"{path} names {payload.get('class_names')} for {model_config.num_classes} classes")
    speed_scale = payload.get("speed_scale_mps")
    if not isinstance(speed_scale, float) or speed_scale <= 0.0:
        raise CheckpointError(f"{path} has no positive speed_scale_mps (got {speed_scale!r})")
    return model_config, preprocess


def read_configs(path: Path | str) -> tuple[MSFSUConfig, PreprocessConfig]:
    """A checkpoint's network and preprocessing configuration, without building the network."""
    path = Path(path)
    return _configs(_read_payload(path), path)


def load_checkpoint(path: Path | str, with_training_state: bool = False) -> LoadedCheckpoint:
    """Rebuild the network (fp32, eval mode) and its configuration; CheckpointError if anything is off."""
    path = Path(path)
    payload = _read_payload(path)
    model_config, preprocess = _configs(payload, path)
    model = build_model(model_config)
    state_dict = payload.get("state_dict")
    if not isinstance(state_dict, dict):
        raise CheckpointError(f"{path} has no state dict")
    try:
        model.load_state_dict(state_dict, strict=True)  # copies into the fp32 parameters
    except RuntimeError as error:
        raise CheckpointError(f"{path}: weights do not match its configuration {model_config}: {error}") from error
    return LoadedCheckpoint(
        model=model.eval(),
        preprocess=preprocess,
        speed_scale=payload["speed_scale_mps"],
        class_names=tuple(payload["class_names"]),
        training=dict(payload.get("training", {})),
        training_state=payload.get("training_state") if with_training_state else None,
    )


def release_checkpoint(source: Path | str, destination: Path | str) -> Path:
    """A deployable copy of a training checkpoint: fp16 storage, no training state (about half the size)."""
    loaded = load_checkpoint(source)
    save_checkpoint(destination, loaded.model, loaded.preprocess, loaded.speed_scale, loaded.training, half=True)
    return Path(destination)


def main(argv: list[str] | None = None) -> int:
    """`msfsu-release-checkpoint runs/x/best.pt models/x.pt`: what the repository ships."""
    parser = argparse.ArgumentParser(prog="msfsu-release-checkpoint", description=release_checkpoint.__doc__)
    parser.add_argument("source", type=Path, help="checkpoint written by msfsu-train (best.pt)")
    parser.add_argument("destination", type=Path, help="fp16 checkpoint to write")
    args = parser.parse_args(argv)
    try:
        destination = release_checkpoint(args.source, args.destination)
    except CheckpointError as error:
        print(f"msfsu-release-checkpoint: {error}", file=sys.stderr)
        return 1
    print(f"{destination}: {destination.stat().st_size / 2**20:.1f} MiB (fp16 storage, fp32 when loaded)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
