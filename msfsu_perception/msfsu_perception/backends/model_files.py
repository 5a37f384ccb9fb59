"""Model files derived from a checkpoint, shared by the backends that run the exported network (cached in
`<checkpoint>.deploy/`, msfsu_perception.deploy_files): the fp32 ONNX export and the int8 build's inputs."""

from __future__ import annotations

import logging
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from msfsu_perception.deploy_files import CalibrationSet, DeployFiles, calibration_path
from msfsu_perception.export import export_onnx
from msfsu_perception.int8_recipe import Int8Build, load_recipe
from msfsu_perception.model import MSFSUNet

log = logging.getLogger(__name__)


def onnx_fp32(store: DeployFiles, network: MSFSUNet) -> Path:
    return store.get("fp32.onnx", lambda path: export_onnx(network, path, class_ids=True))


def calibration_feeds(calibration: CalibrationSet) -> Iterator[dict[str, np.ndarray]]:
    for inputs, command_index in calibration.batches():
        yield {"inputs": inputs, "command_index": command_index}


def int8_build(checkpoint: Path, calibration: CalibrationSet | None = None) -> Int8Build | None:
    """What this checkpoint's int8 model is made from now (calibration frames + recipe); None without usable frames."""
    if calibration is None:
        path = calibration_path(checkpoint)
        if not path.is_file():
            return None
        try:
            calibration = CalibrationSet.load(path)
        except ValueError as error:
            log.warning("int8 cannot be built: %s", error)
            return None
    recipe = load_recipe(checkpoint)
    return Int8Build(calibration.digest, recipe.digest, recipe.keep_float)
