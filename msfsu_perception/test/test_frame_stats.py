"""FrameStats: the perception node's counters and the /diagnostics values made of them (no ROS)."""

from __future__ import annotations

from collections import Counter

from msfsu_common.road_option import RoadOption
from msfsu_perception.frame_scheduler import Command, FrameScheduler
from msfsu_perception.frame_stats import LATENCY_WINDOW, FrameStats


def test_before_any_frame_a_report_has_the_counters_and_no_timings():
    report = FrameStats(now=0.0).report(1.0, FrameScheduler(), Counter())
    assert report.values == {"processed": 0, "skipped_newer_frame": 0, "rate_hz": 0.0, "command": "LANE_FOLLOW",
                             "command_wait_timeouts": 0, "depth_frames_with_invalid_pixels": 0}
    assert not report.dropping


def test_served_frames_give_the_rate_since_the_last_report_the_timings_and_the_depth_holes():
    stats, scheduler = FrameStats(now=0.0), FrameScheduler()
    scheduler.on_command(Command(RoadOption.LEFT, 1))
    for compute_ms, share in ((10.0, 0.0), (20.0, 0.25), (30.0, None)):
        stats.served(compute_ms, stamp_latency_ms=2 * compute_ms, depth_invalid_share=share)
    values = stats.report(2.0, scheduler, Counter()).values
    assert (values["processed"], values["rate_hz"], values["command"]) == (3, 1.5, "LEFT")
    assert (values["depth_frames_with_invalid_pixels"], values["depth_invalid_share_max"]) == (1, 0.25)
    assert (values["compute_ms_p50"], values["compute_ms_p95"], values["compute_ms_max"]) == (20.0, 29.0, 30.0)
    assert values["stamp_latency_ms_max"] == 60.0
    stats.served(5.0, 5.0, None)
    assert stats.report(4.0, scheduler, Counter()).values["rate_hz"] == 0.5  # one frame in the 2 s since


def test_timings_cover_the_last_window_of_frames():
    stats = FrameStats(now=0.0)
    for index in range(LATENCY_WINDOW + 10):
        stats.served(float(index), 0.0, None)
    assert len(stats.compute_ms) == LATENCY_WINDOW and stats.compute_ms[0] == 10.0


def test_drops_are_counted_by_reason_with_the_synchronizers_and_a_report_says_when_inputs_were_dropped():
    stats, scheduler = FrameStats(now=0.0), FrameScheduler()
    assert stats.drop("bad_rgb") == 1 and stats.drop("bad_rgb") == 2
    report = stats.report(1.0, scheduler, Counter(unpaired_a=1))
    assert (report.values["dropped_bad_rgb"], report.values["dropped_unpaired_a"], report.dropping) == (2, 1, True)
    assert not stats.report(2.0, scheduler, Counter(unpaired_a=1)).dropping  # nothing new since
    assert stats.report(3.0, scheduler, Counter(unpaired_a=2)).dropping
