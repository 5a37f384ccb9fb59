"""The files derived from one checkpoint, kept beside it: this module alone names them and lays them out.

    models/msfsu_default.pt                                 the checkpoint (msfsu-train / msfsu-release-checkpoint)
    models/msfsu_default.pt.calibration.npz                 int8 calibration frames (msfsu_perception.calibration)
    models/msfsu_default.pt.deploy/<digest>-v<N>-fp32.onnx  converted models, built on first use (backends)
    models/msfsu_default.pt.deploy/<digest>-v<N>-int8-<calibration digest>-<recipe digest>.xml / .onnx
    models/msfsu_default.pt.deploy/<digest>-v<N>-int8-recipe.json  layers kept in float for int8 (int8_recipe; committed)
    models/msfsu_default.pt.deploy/<digest>-v<N>-openvino-cache/
    models/msfsu_default.pt.deploy/<digest>-v<N>-gate.json  accuracy-gate verdicts (gate_verdicts; committed)
    models/msfsu_default.pt.deploy/<digest>-v<N>-gate-cuda.json  the same for the GPU paths

<digest> is the checkpoint's content hash and N the deploy format version, so nothing derived from an older
version of a checkpoint (or an older export recipe) is ever used; building a file removes the others.
Numpy only: the live node reads these without the training data pipeline.
"""

from __future__ import annotations

import hashlib
import os
import shutil
import zipfile
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path

import numpy as np

DEPLOY_FORMAT_VERSION = 3  # bump when the exported graph or the quantisation recipe changes
# 2: int8 recipes (layers kept in float) and gate verdicts pooled over several held-out bags
# 3: non-overlapping transposed convolutions of stride > 3 exported as 1x1 convolution + DepthToSpace (export.py)


def file_digest(path: Path) -> str:
    digest = hashlib.sha256()
    with path.open("rb") as stream:
        while chunk := stream.read(1 << 20):
            digest.update(chunk)
    return digest.hexdigest()[:16]


def calibration_path(checkpoint: Path) -> Path:
    """`<checkpoint>.calibration.npz`: preprocessed training frames for int8 quantisation."""
    return checkpoint.with_name(checkpoint.name + ".calibration.npz")


class DeployFiles:
    """`<checkpoint>.deploy/`: the derived files of one checkpoint version."""

    def __init__(self, checkpoint: Path) -> None:
        self.checkpoint = checkpoint
        self.directory = checkpoint.with_name(checkpoint.name + ".deploy")

    @cached_property
    def prefix(self) -> str:
        return f"{file_digest(self.checkpoint)}-v{DEPLOY_FORMAT_VERSION}"

    @property
    def gate_record(self) -> Path:
        """The verdicts of the CPU paths."""
        return self.directory / f"{self.prefix}-gate.json"

    def gate_record_of(self, device: str) -> Path:
        """The verdicts of one device's paths (their own held-out frames: a GPU's gate may run elsewhere)."""
        return self.gate_record if device == "cpu" else self.directory / f"{self.prefix}-gate-{device}.json"

    @property
    def int8_recipe(self) -> Path:
        return self.directory / f"{self.prefix}-int8-recipe.json"

    @property
    def openvino_cache(self) -> Path:
        return self.directory / f"{self.prefix}-openvino-cache"

    def get(self, name: str, build: Callable[[Path], None]) -> Path:
        """The file `<prefix>-<name>`, written by build(temporary path) if missing, then renamed."""
        path = self.directory / f"{self.prefix}-{name}"
        if path.is_file():
            return path
        self.directory.mkdir(parents=True, exist_ok=True)
        self._remove_other_versions()
        temporary = path.with_name(f".{path.name}.{os.getpid()}.partial{path.suffix}")
        build(temporary)
        if temporary.suffix == ".xml":  # OpenVINO IR: weights beside the graph
            os.replace(temporary.with_suffix(".bin"), path.with_suffix(".bin"))
        os.replace(temporary, path)
        return path

    def _remove_other_versions(self) -> None:
        for stale in self.directory.iterdir():
            if stale.name.startswith((self.prefix, ".")):
                continue
            if stale.is_dir():
                shutil.rmtree(stale, ignore_errors=True)
            else:
                stale.unlink(missing_ok=True)


def cached_inputs(rgb: np.ndarray, depth: np.ndarray | None, out: np.ndarray) -> np.ndarray:
    """Frame-cache layout -> the float32 (C, h, w) network input preprocess_frame produced (depth rounded to fp16)."""
    np.multiply(rgb, np.float32(1.0 / 255.0), out=out[:3])
    if depth is not None:
        out[3:] = depth
    return out


@dataclass(frozen=True, eq=False)
class CalibrationSet:
    """The calibration frames file: preprocessed frames in the frame cache's compact layout."""

    path: Path
    rgb: np.ndarray  # (N, 3, h, w) uint8
    depth: np.ndarray | None  # (N, 1, h, w) float16
    command_index: np.ndarray  # (N,) int64, RoadOption.branch_index

    @classmethod
    def load(cls, path: Path) -> CalibrationSet:
        """ValueError when the file is not a calibration frames file."""
        try:
            with np.load(path) as arrays:
                depth = arrays["depth"] if "depth" in arrays.files else None
                return cls(path, arrays["rgb"], depth, arrays["command_index"])
        except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile) as error:
            raise ValueError(f"{path} is not a calibration frames file ({error}): write it again "
                             "(msfsu-calibrate)") from None

    @cached_property
    def digest(self) -> str:
        """Hash of the frames themselves, not of the file (a zip archive carries its writing time)."""
        digest = hashlib.sha256()
        for array in (self.rgb, self.depth, self.command_index):
            if array is not None:
                digest.update(f"{array.dtype}{array.shape}".encode())
                digest.update(np.ascontiguousarray(array).tobytes())
        return digest.hexdigest()[:16]

    @classmethod
    def for_checkpoint(cls, checkpoint: Path) -> CalibrationSet | None:
        path = calibration_path(checkpoint)
        return cls.load(path) if path.is_file() else None

    def __len__(self) -> int:
        return len(self.command_index)

    def batches(self) -> Iterator[tuple[np.ndarray, np.ndarray]]:
        """Batch-1 network inputs: (1, C, h, w) float32 and (1,) int64."""
        channels = 3 if self.depth is None else 4
        for row in range(len(self)):
            inputs = np.empty((1, channels, *self.rgb.shape[2:]), np.float32)
            cached_inputs(self.rgb[row], None if self.depth is None else self.depth[row], inputs[0])
            yield inputs, self.command_index[row : row + 1]
