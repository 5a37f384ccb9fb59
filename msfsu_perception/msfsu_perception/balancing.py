"""Balancing of the lane-following samples, exactly as paper III-B describes it.

For LANE_FOLLOW samples only (other commands are kept once each, untouched):
1. steering in degrees = normalised steer * 70; randomly discard 80 % of the samples with
   |steer| < 5 deg (exactly round(0.8 * n) of them, chosen with the seeded generator);
2. "duplicate the rest six times and append them": every sample with |steer| >= 5 deg gets
   6 extra copies, i.e. appears 7 times;
3. "duplicate the processed samples with speed below 1 m/s three times": every sample of the
   result of 1-2 (copies included) whose expert target speed is < 1 m/s gets 3 extra copies
   (4 times in total; a slow sharp-turn sample thus appears 7 * 4 = 28 times).
The result is a list of row indices (duplicates repeated), sorted; the loader shuffles.

`repeat_focus` then gives the focus frames of on-policy data (bag_index.FocusConfig: where the network crashed or
nearly did) extra copies (DAgger aimed at the network's failures; `msfsu-train --focus-copies`, off by default).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from msfsu_common.road_option import RoadOption


@dataclass(frozen=True)
class BalancingConfig:
    steer_to_degrees: float = 70.0
    small_steer_deg: float = 5.0
    small_steer_discard_fraction: float = 0.8
    sharp_steer_extra_copies: int = 6
    slow_speed_mps: float = 1.0
    slow_extra_copies: int = 3


def balance_lane_follow(
    steer: np.ndarray,
    target_speed_mps: np.ndarray,
    command: np.ndarray,
    rng: np.random.Generator,
    config: BalancingConfig = BalancingConfig(),
) -> np.ndarray:
    """(N,) steer, speed [m/s], RoadOption values -> (M,) int64 indices into them, with repeats."""
    lane_follow = command == RoadOption.LANE_FOLLOW
    small = np.abs(steer * config.steer_to_degrees) < config.small_steer_deg
    small_rows = np.flatnonzero(lane_follow & small)
    keep_count = len(small_rows) - int(round(config.small_steer_discard_fraction * len(small_rows)))
    kept_small = rng.choice(small_rows, size=keep_count, replace=False)
    sharp = np.flatnonzero(lane_follow & ~small)
    processed = np.concatenate([kept_small, np.repeat(sharp, 1 + config.sharp_steer_extra_copies)])
    slow = processed[target_speed_mps[processed] < config.slow_speed_mps]
    lane_follow_rows = np.concatenate([processed, np.repeat(slow, config.slow_extra_copies)])
    return np.sort(np.concatenate([np.flatnonzero(~lane_follow), lane_follow_rows])).astype(np.int64)


def repeat_focus(rows: np.ndarray, focus: np.ndarray, extra_copies: int) -> np.ndarray:
    """`rows` (balanced, with repeats) plus `extra_copies` more of every entry whose row is a focus frame
    (`focus` is indexed by row), sorted. With 0 copies, `rows` unchanged."""
    rows = np.asarray(rows, np.int64)
    if extra_copies < 0:
        raise ValueError(f"extra copies must be >= 0, not {extra_copies}")
    chosen = rows[np.asarray(focus, bool)[rows]]
    return np.sort(np.concatenate([rows, np.repeat(chosen, extra_copies)])).astype(np.int64)
