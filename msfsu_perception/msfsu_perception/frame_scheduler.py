"""Which paired frame the perception node infers next, and with which navigation command (ROS-free).

Rules:
- Skip to the newest: one frame waits for inference at a time; a frame offered while another waits replaces it,
  and the replaced one is counted as skipped. A slow network never builds a backlog.
- Command wait (`command_wait` > 0, lockstep): a frame taken for inference is held until a command stamped at or
  after it arrives, and is then served with that command. One frame is held at a time: a newer frame taken while
  one is held replaces it (counted as skipped). A held frame whose command has not come by its deadline (taken +
  `command_wait`, monotonic seconds) is served with the latest command, counted as a command timeout. A new
  `command_wait` applies to frames taken after it; a held frame keeps its deadline, except that 0 serves it at once.
- Without the wait (`command_wait` 0), a taken frame is served at once with the latest command.

The caller says what time it is (`now`, monotonic seconds) and infers every `Served` it is handed at once.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from msfsu_common.road_option import RoadOption
from msfsu_perception.latest_slot import LatestSlot

if TYPE_CHECKING:
    from msfsu_common.stage_times import Marks, StageTrace


@dataclass(frozen=True)
class DecodedImage:
    """One decoded camera message: its header (copied onto what is published for it), pixels and stage marks."""

    header: Any  # std_msgs/Header
    pixels: np.ndarray
    marks: Marks


@dataclass(frozen=True)
class Frame:
    """A camera frame to infer: RGB with the depth paired with it (None for an RGB-only network)."""

    stamp_ns: int  # the RGB image's stamp
    header: Any  # the RGB image's std_msgs/Header
    rgb: np.ndarray  # (H, W, 3) uint8
    depth: np.ndarray | None  # (H, W) float32 metres, as decoded (not yet sanitized)
    trace: StageTrace


@dataclass(frozen=True)
class Command:
    """A navigation command and its stamp."""

    option: RoadOption
    stamp_ns: int


@dataclass(frozen=True)
class Served:
    """A frame to infer now, with the command to infer it with."""

    frame: Frame
    command: RoadOption


@dataclass(frozen=True)
class Held:
    """A frame waiting for its command until `deadline` (monotonic seconds)."""

    frame: Frame
    deadline: float


class FrameScheduler:
    """The frame-scheduling rules of the module docstring, with their counters (`skipped`, `command_timeouts`)."""

    def __init__(self, command_wait: float = 0.0) -> None:
        self.command_wait = command_wait
        self.command = RoadOption.LANE_FOLLOW  # the latest command
        self.command_stamp_ns: int | None = None
        self.held: Held | None = None
        self.skipped = 0  # frames replaced by a newer one before they were served
        self.command_timeouts = 0  # held frames served with the latest command after waiting command_wait
        self._waiting: LatestSlot[Frame] = LatestSlot()

    def offer(self, frame: Frame) -> None:
        """`frame` waits for inference in place of any frame still waiting (counted as skipped)."""
        if self._waiting.put(frame) is not None:
            self.skipped += 1

    def take(self, now: float) -> Served | None:
        """The waiting frame, to serve now, or None: nothing waits, or the frame is held for its command."""
        frame = self._waiting.take()
        if frame is None:
            return None
        if self.command_wait > 0 and not self._has_command_for(frame):
            if self.held is not None:
                self.skipped += 1
            self.held = Held(frame, now + self.command_wait)
            return None
        return Served(frame, self.command)

    def on_command(self, command: Command) -> Served | None:
        """`command` is the latest; the held frame it is stamped for (at or after it) is served with it."""
        self.command, self.command_stamp_ns = command.option, command.stamp_ns
        if self.held is not None and self._has_command_for(self.held.frame):
            return self._release()
        return None

    def release_overdue(self, now: float) -> Served | None:
        """The held frame whose deadline has passed, served with the latest command (a command timeout)."""
        if self.held is None or now < self.held.deadline:
            return None
        self.command_timeouts += 1
        return self._release()

    def set_command_wait(self, wait_s: float) -> Served | None:
        """`wait_s` applies to frames taken from now on; at 0 the held frame is served at once (no timeout)."""
        self.command_wait = wait_s
        if wait_s == 0 and self.held is not None:
            return self._release()
        return None

    def clear(self) -> None:
        """Forget the waiting and held frames and the command, as a new scheduler would (a node deactivated: what
        comes after its next activation is a new stream); the counters stay."""
        self._waiting.take()
        self.held = None
        self.command, self.command_stamp_ns = RoadOption.LANE_FOLLOW, None

    def _has_command_for(self, frame: Frame) -> bool:
        return self.command_stamp_ns is not None and self.command_stamp_ns >= frame.stamp_ns

    def _release(self) -> Served:
        frame, self.held = self.held.frame, None
        return Served(frame, self.command)
