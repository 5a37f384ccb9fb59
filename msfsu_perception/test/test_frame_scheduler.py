"""FrameScheduler: skip to the newest frame, the command wait's hold and release, its counters (no ROS)."""

from __future__ import annotations

import subprocess
import sys

import numpy as np

from msfsu_common.road_option import RoadOption
from msfsu_perception.frame_scheduler import Command, Frame, FrameScheduler, Served

RGB = np.zeros((2, 2, 3), np.uint8)


def frame(stamp_ns: int) -> Frame:
    return Frame(stamp_ns, header=None, rgb=RGB, depth=None, trace=None)


def served(result: Served | None) -> tuple[int, RoadOption] | None:
    return None if result is None else (result.frame.stamp_ns, result.command)


def test_without_a_wait_a_frame_is_served_at_once_with_the_latest_command():
    scheduler = FrameScheduler(command_wait=0.0)
    assert scheduler.on_command(Command(RoadOption.LEFT, 5)) is None
    scheduler.offer(frame(10))
    assert served(scheduler.take(now=0.0)) == (10, RoadOption.LEFT)  # a command older than the frame: no wait
    assert scheduler.take(now=0.0) is None  # nothing waits any more
    assert (scheduler.skipped, scheduler.command_timeouts) == (0, 0)


def test_the_first_frame_without_any_command_is_served_with_lane_follow():
    scheduler = FrameScheduler()
    scheduler.offer(frame(10))
    assert served(scheduler.take(now=0.0)) == (10, RoadOption.LANE_FOLLOW)


def test_frames_offered_while_one_waits_skip_to_the_newest():
    scheduler = FrameScheduler()
    for stamp in (10, 20, 30):
        scheduler.offer(frame(stamp))
    assert served(scheduler.take(now=0.0)) == (30, RoadOption.LANE_FOLLOW)
    assert scheduler.skipped == 2


def test_a_frame_is_held_until_the_command_stamped_for_it_and_served_with_that_command():
    scheduler = FrameScheduler(command_wait=5.0)
    scheduler.offer(frame(100))
    assert scheduler.take(now=0.0) is None  # held
    assert scheduler.on_command(Command(RoadOption.RIGHT, 90)) is None  # older than the frame: still held
    assert scheduler.held is not None and scheduler.command == RoadOption.RIGHT
    assert served(scheduler.on_command(Command(RoadOption.LEFT, 100))) == (100, RoadOption.LEFT)
    assert scheduler.held is None and scheduler.command_timeouts == 0


def test_a_command_stamped_after_the_held_frame_releases_it_too():
    scheduler = FrameScheduler(command_wait=5.0)
    scheduler.offer(frame(100))
    scheduler.take(now=0.0)
    assert served(scheduler.on_command(Command(RoadOption.STRAIGHT, 150))) == (100, RoadOption.STRAIGHT)


def test_a_frame_whose_command_is_there_already_is_not_held():
    scheduler = FrameScheduler(command_wait=5.0)
    scheduler.on_command(Command(RoadOption.LEFT, 100))
    scheduler.offer(frame(100))
    assert served(scheduler.take(now=0.0)) == (100, RoadOption.LEFT)


def test_a_held_frame_is_served_with_the_latest_command_at_its_deadline_and_counted():
    scheduler = FrameScheduler(command_wait=0.2)
    scheduler.offer(frame(100))
    scheduler.take(now=10.0)
    scheduler.on_command(Command(RoadOption.RIGHT, 50))
    assert scheduler.release_overdue(now=10.19) is None
    assert served(scheduler.release_overdue(now=10.2)) == (100, RoadOption.RIGHT)
    assert scheduler.command_timeouts == 1
    assert scheduler.release_overdue(now=11.0) is None  # nothing held any more
    assert scheduler.command_timeouts == 1


def test_a_newer_frame_replaces_the_held_one_counted_as_skipped():
    scheduler = FrameScheduler(command_wait=1.0)
    scheduler.offer(frame(100))
    scheduler.take(now=0.0)
    scheduler.offer(frame(200))
    assert scheduler.take(now=0.5) is None
    assert scheduler.held.frame.stamp_ns == 200 and scheduler.held.deadline == 1.5
    assert scheduler.skipped == 1
    assert scheduler.on_command(Command(RoadOption.LEFT, 150)) is None  # the replaced frame's command
    assert served(scheduler.on_command(Command(RoadOption.RIGHT, 200))) == (200, RoadOption.RIGHT)


def test_command_wait_set_to_0_serves_the_held_frame_at_once_without_a_timeout():
    scheduler = FrameScheduler(command_wait=5.0)
    scheduler.offer(frame(100))
    scheduler.take(now=0.0)
    assert served(scheduler.set_command_wait(0.0)) == (100, RoadOption.LANE_FOLLOW)
    assert scheduler.command_timeouts == 0 and scheduler.held is None
    scheduler.offer(frame(200))
    assert served(scheduler.take(now=0.0)) == (200, RoadOption.LANE_FOLLOW)  # no wait from now on


def test_a_new_command_wait_leaves_the_held_frames_deadline_and_applies_to_the_next_frame():
    scheduler = FrameScheduler(command_wait=5.0)
    scheduler.offer(frame(100))
    scheduler.take(now=0.0)
    assert scheduler.set_command_wait(1.0) is None
    assert scheduler.release_overdue(now=4.9) is None  # still the 5 s it was taken with
    assert served(scheduler.release_overdue(now=5.0)) == (100, RoadOption.LANE_FOLLOW)
    scheduler.offer(frame(200))
    scheduler.take(now=10.0)
    assert scheduler.held.deadline == 11.0


def test_a_command_wait_set_above_0_holds_the_next_frame():
    scheduler = FrameScheduler(command_wait=0.0)
    assert scheduler.set_command_wait(0.1) is None
    scheduler.offer(frame(100))
    assert scheduler.take(now=0.0) is None and scheduler.held.deadline == 0.1


def test_clear_forgets_the_waiting_and_held_frames_and_the_command_and_keeps_the_counters():
    scheduler = FrameScheduler(command_wait=5.0)
    scheduler.on_command(Command(RoadOption.LEFT, 50))
    scheduler.offer(frame(100))
    scheduler.take(now=0.0)  # held for its command
    scheduler.offer(frame(110))
    scheduler.offer(frame(120))  # 110 skipped
    scheduler.clear()
    assert scheduler.held is None and scheduler.take(now=0.0) is None and scheduler.skipped == 1
    assert scheduler.release_overdue(now=10.0) is None  # the held frame is gone, not served late
    assert (scheduler.command, scheduler.command_stamp_ns) == (RoadOption.LANE_FOLLOW, None)


def test_the_scheduler_stats_and_infer_frame_import_no_ros():
    probe = ("import sys, msfsu_perception.frame_scheduler, msfsu_perception.frame_inference, "
             "msfsu_perception.frame_stats; "
             "print(sorted(m for m in sys.modules if m.startswith('rclpy')))")
    run = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, timeout=60)
    assert run.returncode == 0, run.stderr[-2000:]
    assert run.stdout.strip() == "[]"
