"""The perception node's frame counters and recent timings, and the /diagnostics values made of them (ROS-free).

A report's values: `processed`, `skipped_newer_frame` and `command_wait_timeouts` (the scheduler's), `rate_hz`
(frames served per second since the previous report), `command` (the latest), `depth_frames_with_invalid_pixels`,
`depth_invalid_share_max`, p50, p95 and max of `compute_ms` and `stamp_latency_ms` (the last LATENCY_WINDOW frames
served; left out before the first), and `dropped_<reason>` for every reason an input was dropped. A report is
`dropping` when an input was dropped since the previous one.
"""

from __future__ import annotations

from collections import Counter, deque
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from msfsu_perception.frame_scheduler import FrameScheduler

LATENCY_WINDOW = 200  # recent frames summarised in a report


@dataclass(frozen=True)
class Report:
    values: dict[str, object]
    dropping: bool  # an input was dropped since the previous report


class FrameStats:
    """Counts what happened to the node's inputs; `report` summarises it."""

    def __init__(self, now: float) -> None:
        self.processed = 0  # frames served
        self.dropped: Counter[str] = Counter()  # inputs dropped, by reason
        self.depth_frames_with_holes = 0  # frames served whose invalid depth pixels were read as far
        self.depth_invalid_share: deque[float] = deque(maxlen=LATENCY_WINDOW)
        self.compute_ms: deque[float] = deque(maxlen=LATENCY_WINDOW)
        self.stamp_latency_ms: deque[float] = deque(maxlen=LATENCY_WINDOW)
        self._last_report = (now, 0, 0)  # time (monotonic s), processed, dropped at the previous report

    def drop(self, reason: str) -> int:
        """Count an input dropped for `reason`; return how many were dropped for it so far."""
        self.dropped[reason] += 1
        return self.dropped[reason]

    def served(self, compute_ms: float, stamp_latency_ms: float, depth_invalid_share: float | None) -> None:
        """Count a frame served (`depth_invalid_share` None: the network reads no depth)."""
        self.processed += 1
        if depth_invalid_share is not None:
            self.depth_invalid_share.append(depth_invalid_share)
            self.depth_frames_with_holes += depth_invalid_share > 0.0
        self.compute_ms.append(compute_ms)
        self.stamp_latency_ms.append(stamp_latency_ms)

    def report(self, now: float, scheduler: FrameScheduler, also_dropped: Mapping[str, int]) -> Report:
        """The values at `now` (monotonic s); `also_dropped` are drops counted elsewhere (the synchronizer's)."""
        dropped = self.dropped + Counter(also_dropped)
        last_time, last_processed, last_dropped = self._last_report
        self._last_report = (now, self.processed, dropped.total())
        values: dict[str, object] = {
            "processed": self.processed,
            "skipped_newer_frame": scheduler.skipped,
            "rate_hz": (self.processed - last_processed) / max(now - last_time, 1e-9),
            "command": scheduler.command.name,
            "command_wait_timeouts": scheduler.command_timeouts,
            "depth_frames_with_invalid_pixels": self.depth_frames_with_holes,
        }
        if self.depth_invalid_share:
            values["depth_invalid_share_max"] = max(self.depth_invalid_share)
        for name, window in (("compute_ms", self.compute_ms), ("stamp_latency_ms", self.stamp_latency_ms)):
            if window:
                samples = np.fromiter(window, np.float64)
                values[f"{name}_p50"], values[f"{name}_p95"] = (float(v) for v in np.percentile(samples, [50, 95]))
                values[f"{name}_max"] = float(samples.max())
        values.update({f"dropped_{reason}": count for reason, count in sorted(dropped.items())})
        return Report(values, dropped.total() > last_dropped)
