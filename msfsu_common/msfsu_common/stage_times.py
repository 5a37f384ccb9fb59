"""Per-frame stage times of a node, published as msfsu_interfaces/StageTimes for latency tracing.

A node that traces builds one `StageTrace` per camera frame, marks each stage with the wall clock
(`time.time_ns()`, CLOCK_REALTIME: comparable between the processes of one machine, whatever clock the node
runs on) and publishes it on topics.STAGE_TIMES. A received message brings three marks: `<name>_sent` (its
writer's DDS write, rmw's `source_timestamp`), `<name>_dds` (the middleware here had it, `received_timestamp`)
and `<name>_taken` (the callback started): transport, then the wait for the node's executor.
"""

from __future__ import annotations

import time
from collections.abc import Mapping
from typing import Any

from msfsu_common import topics
from msfsu_interfaces.msg import StageTimes

Marks = list[tuple[str, int]]


def received(name: str, info: Mapping[str, Any] | None) -> Marks:
    """`<name>_sent`, `<name>_dds` (from the message info, left out without one) and `<name>_taken` (now)."""
    marks = [(f"{name}_{mark}", int(info[key])) for mark, key in (("sent", "source_timestamp"), ("dds", "received_timestamp"))
             if info and info.get(key)]
    return marks + [(f"{name}_taken", time.time_ns())]


class StageTrace:
    """The stages one frame passed in one node."""

    def __init__(self, marks: Marks | None = None) -> None:
        self.marks: Marks = list(marks or [])

    def mark(self, stage: str) -> None:
        self.marks.append((stage, time.time_ns()))

    def message(self, stamp: Any, node_name: str) -> StageTimes:
        msg = StageTimes(stages=[stage for stage, _ in self.marks], times_ns=[t for _, t in self.marks])
        msg.header.stamp = stamp
        msg.header.frame_id = node_name
        return msg


class StageTimesPublisher:
    """Publishes StageTrace messages of `node` while `enabled` (its live `publish_stage_times` parameter); the
    publisher is made the first time it is enabled and kept, silent, while it is not."""

    def __init__(self, node: Any, enabled: bool) -> None:
        self._node = node
        self._publisher = None
        self.enabled = enabled

    @property
    def enabled(self) -> bool:
        return self._enabled

    @enabled.setter
    def enabled(self, enabled: bool) -> None:
        if enabled and self._publisher is None:
            self._publisher = self._node.create_publisher(StageTimes, topics.STAGE_TIMES, 50)
        self._enabled = enabled

    def publish(self, stamp: Any, trace: StageTrace) -> None:
        if self._enabled:
            self._publisher.publish(trace.message(stamp, self._node.get_name()))
