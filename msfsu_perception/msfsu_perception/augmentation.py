"""RGB augmentation of the paper (III-B): Gaussian noise, coarse dropout, contrast normalisation,
Gaussian blur, each applied independently with probability 0.1. Depth and labels are untouched.

Magnitudes follow imgaug's usual settings (the paper names imgaug's operations without values).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import cv2
import numpy as np

OPERATIONS = ("gaussian_noise", "coarse_dropout", "contrast", "gaussian_blur")


@dataclass(frozen=True)
class AugmentationConfig:
    probability: float = 0.1  # of each operation, independently
    noise_sigma_max: float = 0.05 * 255  # sigma ~ U(0, max), uint8 units
    dropout_fraction_max: float = 0.1  # fraction of coarse cells zeroed ~ U(0, max)
    dropout_cell_fraction: tuple[float, float] = (0.02, 0.25)  # cell size / image size
    contrast_range: tuple[float, float] = (0.5, 1.5)  # v' = 128 + alpha * (v - 128)
    blur_sigma_max: float = 1.5  # sigma ~ U(0, max) pixels


class Augmented(NamedTuple):
    image: np.ndarray  # (3, h, w) uint8
    applied: tuple[str, ...]  # names from OPERATIONS, in order of application


def _gaussian_noise(hwc: np.ndarray, rng: np.random.Generator, config: AugmentationConfig) -> np.ndarray:
    sigma = rng.uniform(0, config.noise_sigma_max)
    return hwc.astype(np.float32) + rng.normal(0, sigma, hwc.shape).astype(np.float32)


def _coarse_dropout(hwc: np.ndarray, rng: np.random.Generator, config: AugmentationConfig) -> np.ndarray:
    height, width = hwc.shape[:2]
    cell = rng.uniform(*config.dropout_cell_fraction)
    grid = (max(1, round(1 / cell)), max(1, round(1 / cell)))
    dropped = (rng.random(grid) < rng.uniform(0, config.dropout_fraction_max)).astype(np.uint8)
    mask = cv2.resize(dropped, (width, height), interpolation=cv2.INTER_NEAREST).astype(bool)
    return np.where(mask[..., None], np.float32(0), hwc)


def _contrast(hwc: np.ndarray, rng: np.random.Generator, config: AugmentationConfig) -> np.ndarray:
    return 128.0 + rng.uniform(*config.contrast_range) * (hwc.astype(np.float32) - 128.0)


def _gaussian_blur(hwc: np.ndarray, rng: np.random.Generator, config: AugmentationConfig) -> np.ndarray:
    sigma = max(rng.uniform(0, config.blur_sigma_max), 1e-3)
    return cv2.GaussianBlur(hwc.astype(np.float32), (0, 0), sigmaX=sigma)


_OPERATIONS = {
    "gaussian_noise": _gaussian_noise,
    "coarse_dropout": _coarse_dropout,
    "contrast": _contrast,
    "gaussian_blur": _gaussian_blur,
}


def apply_operation(name: str, rgb: np.ndarray, rng: np.random.Generator, config: AugmentationConfig) -> np.ndarray:
    """One operation of OPERATIONS on (3, h, w) uint8 -> (3, h, w) uint8 (saturating)."""
    result = _OPERATIONS[name](rgb.transpose(1, 2, 0), rng, config)
    return np.ascontiguousarray(np.clip(np.rint(result), 0, 255).astype(np.uint8).transpose(2, 0, 1))


def augment_rgb(rgb: np.ndarray, rng: np.random.Generator, config: AugmentationConfig) -> Augmented:
    """(3, h, w) uint8 -> Augmented; the input is returned unchanged (same object) when nothing fires."""
    chosen = tuple(name for name, draw in zip(OPERATIONS, rng.random(len(OPERATIONS))) if draw < config.probability)
    for name in chosen:
        rgb = apply_operation(name, rgb, rng, config)
    return Augmented(rgb, chosen)
