"""`preprocess_frame` on a torch device: the same crop, area resize and scaling, computed where the network runs.

For a GPU-backed node (issue 26): only the camera's uint8 RGB (and float32 depth) cross to the device, not the
float32 network input, and the resize runs there. OpenCV's INTER_AREA, which `preprocess_frame` uses, is for a
downscale the mean of the source pixels each output pixel covers, partial pixels weighted by the part covered;
here it is the same as two matrix products, `rows @ image @ columns.T`, with those coverage weights. RGB is
rounded to uint8 between the resize and the scaling, as OpenCV's uint8 resize does, so RGB agrees with
`preprocess_frame` to the last bit wherever the exact mean is not within float rounding of a half (then one step
of 1/255); depth agrees to float32 rounding. An upscale (a camera smaller than the network input after the
crop) is not an area resize in OpenCV and is refused here: `preprocess_frame` serves it.
"""

from __future__ import annotations

import numpy as np
import torch

from msfsu_perception.preprocessing import PreprocessConfig, crop_rows


def area_weights(source: int, target: int) -> np.ndarray:
    """(target, source) float64 matrix: row i averages the source pixels output pixel i covers (OpenCV INTER_AREA)."""
    if not 0 < target <= source:
        raise ValueError(f"an area resize shrinks: {source} -> {target} pixels")
    scale = source / target
    weights = np.zeros((target, source))
    for i in range(target):
        start, end = i * scale, (i + 1) * scale
        for j in range(int(np.floor(start)), min(int(np.ceil(end)), source)):
            weights[i, j] = (min(end, j + 1) - max(start, j)) / scale
    return weights


class DevicePreprocessor:
    """`preprocess_frame` for one camera size on `device`: __call__(rgb uint8 (H, W, 3), depth float32 (H, W) or
    None) -> (1, C, h, w) float32 on the device. Depth must have gone through `sanitize_depth` (inf = far)."""

    def __init__(self, config: PreprocessConfig, camera_height: int, camera_width: int,
                 device: torch.device | str) -> None:
        self.config, self.device = config, torch.device(device)
        self.rows = crop_rows(camera_height, config)
        cropped = self.rows.stop - self.rows.start
        self.row_weights = torch.from_numpy(area_weights(cropped, config.input_height)).float().to(self.device)
        self.column_weights = torch.from_numpy(area_weights(camera_width, config.input_width).T).float().to(self.device)
        self.camera_shape = (camera_height, camera_width)

    def _resize(self, planes: torch.Tensor) -> torch.Tensor:
        """(P, H', W) float32 -> (P, h, w) area means."""
        return self.row_weights @ planes @ self.column_weights

    def __call__(self, rgb: np.ndarray, depth: np.ndarray | None) -> torch.Tensor:
        if rgb.shape != (*self.camera_shape, 3) or rgb.dtype != np.uint8:
            raise ValueError(f"rgb must be {self.camera_shape} x 3 uint8, got {rgb.shape} {rgb.dtype}")
        rows = self.rows
        image = torch.from_numpy(np.ascontiguousarray(rgb[rows])).to(self.device, non_blocking=True)
        channels = [self._resize(image.permute(2, 0, 1).float()).round_().clamp_(0.0, 255.0).mul_(1.0 / 255.0)]
        if self.config.use_depth:
            if depth is None or depth.shape != self.camera_shape:
                raise ValueError(f"depth must be {self.camera_shape} matching rgb, got "
                                 f"{None if depth is None else depth.shape}")
            metres = torch.from_numpy(np.ascontiguousarray(depth[rows])).to(self.device, non_blocking=True)
            clipped = metres.clamp_(max=self.config.max_depth_m)
            channels.append(self._resize(clipped[None]).mul_(1.0 / self.config.max_depth_m).clamp_(0.0, 1.0))
        return torch.cat(channels)[None]
