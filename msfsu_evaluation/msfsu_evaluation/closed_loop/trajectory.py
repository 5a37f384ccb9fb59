"""Closeness to the expert (paper IV, Table 3): trajectory RMSE in metres, ROS-free.

    RMSE = 1/N_e * sum_i sqrt( 1/T * sum_t ((x_it - x^E_it)^2 + (y_it - y^E_it)^2) )

over the N_e successful episodes of a task; t runs over the T timesteps of the agent's episode, paired
with the expert's position at the same timestep of its drive of the same route (held at its last
position once the expert has arrived). Timestep pairing also counts a lag along the road; the
`path` variant pairs each agent position with the nearest point of the expert's path instead
(lateral deviation only) and is reported beside it.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np


def _check(agent_xy: np.ndarray, expert_xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    agent, expert = np.asarray(agent_xy, np.float64), np.asarray(expert_xy, np.float64)
    for name, array in (("agent", agent), ("expert", expert)):
        if array.ndim != 2 or array.shape[1] != 2 or len(array) == 0:
            raise ValueError(f"{name} trajectory must be a non-empty (T, 2) array of x, y, got {array.shape}")
    return agent, expert


def episode_rmse(agent_xy: np.ndarray, expert_xy: np.ndarray) -> float:
    """sqrt(mean_t |p_t - p^E_t|^2) over the agent's timesteps (the paper's inner term)."""
    agent, expert = _check(agent_xy, expert_xy)
    paired = expert[np.minimum(np.arange(len(agent)), len(expert) - 1)]
    return float(np.sqrt(np.mean(np.sum((agent - paired) ** 2, axis=1))))


_BLOCK = 16  # agent positions measured against the path at once
_BOUND_STRIDE = 8  # every this many path vertices bound a position's distance to the path from above


def episode_path_rmse(agent_xy: np.ndarray, expert_xy: np.ndarray) -> float:
    """sqrt(mean_t d_t^2), d_t = distance from the agent's position to the expert's path (polyline)."""
    agent, expert = _check(agent_xy, expert_xy)
    if len(expert) == 1:
        return episode_rmse(agent, expert)
    return float(np.sqrt(_path_distances_sq(agent, expert).mean()))


def _path_distances_sq(agent: np.ndarray, expert: np.ndarray) -> np.ndarray:
    """Per agent position, its squared distance to the nearest point of the expert's polyline.

    A block of positions is measured only against the segments that can hold its nearest points: those within the
    block's bounding box widened by an upper bound of its distances (the farthest of its positions from the nearest
    of every `_BOUND_STRIDE`-th path vertex, which lie on the path). Each kept segment's distance is computed as for
    all segments, so the result is the same to the bit, without the (positions x segments) arrays of a long route.
    """
    starts, vectors = expert[:-1], np.diff(expert, axis=0)
    lengths_sq = np.maximum(np.einsum("ij,ij->i", vectors, vectors), 1e-12)
    low_corner, high_corner = np.minimum(starts, expert[1:]), np.maximum(starts, expert[1:])
    vertices = expert[::_BOUND_STRIDE]
    distances_sq = np.empty(len(agent))
    for begin in range(0, len(agent), _BLOCK):
        block = agent[begin:begin + _BLOCK]
        bound = np.sqrt(np.sum((block[:, None, :] - vertices[None]) ** 2, axis=2).min(axis=1).max())
        near = np.all((high_corner >= block.min(axis=0) - bound) & (low_corner <= block.max(axis=0) + bound), axis=1)
        kept_starts, kept_vectors = starts[near], vectors[near]
        offsets = block[:, None, :] - kept_starts[None, :, :]  # (T, S, 2)
        t = np.clip(np.einsum("tsk,sk->ts", offsets, kept_vectors) / lengths_sq[near], 0.0, 1.0)
        nearest = kept_starts[None] + t[..., None] * kept_vectors[None]
        distances_sq[begin:begin + _BLOCK] = np.sum((block[:, None, :] - nearest) ** 2, axis=2).min(axis=1)
    return distances_sq


def task_rmse(episode_values: Sequence[float]) -> float | None:
    """Mean over the successful episodes' RMSE (1/N_e sum_i); None when no episode succeeded."""
    return float(np.mean(episode_values)) if len(episode_values) else None
