"""bag_player: replays a rosbag2 bag (MCAP or sqlite3, via msfsu_common.bag_io) onto the graph.

`ros2 bag play` is not available as a wheel. Messages are published as the recorded CDR bytes
(no decode), at their recorded times divided by `rate`, on reliable publishers with a deep queue;
at the end it waits for every subscriber to acknowledge, so replay loses nothing. Topic remaps are ROS
remaps: `--ros-args -r /old:=/new` (`wait_for` names the remapped topics: the ones subscribers use).

`wait_for` topics gate the playing: it starts once each has a subscriber (`wait_for` may also name topics the
player does not play, e.g. outputs only a recorder subscribes), and it pauses while one has none (a managed node
deactivated mid-bag unsubscribes): the bag's time stops, /clock with it, and goes on from there when the
subscriber is back, so nothing is played into the void. A wait, before or during playing, longer than
`wait_timeout` ends the player with exit code 1 and one line naming the topic and what was played. `start_delay`
and `end_delay` give late matching and nodes still working on the last message (perception) time to catch up.
A damaged or unfinished MCAP bag plays what it holds (every complete chunk, with a warning); a path that
is no bag stops the player with one line naming the file and the reason (exit code 1).
"""

from __future__ import annotations

import argparse
import functools
import sys
import time
from dataclasses import dataclass
from pathlib import Path

from builtin_interfaces.msg import Time as TimeMsg
from rclpy.duration import Duration
from rclpy.node import Node
from rclpy.parameter import Parameter
from rosgraph_msgs.msg import Clock

from msfsu_common.bag_io import BagError, open_bag
from msfsu_common.message_types import message_class
from msfsu_common.node_runner import NodeFailed, NodeFinished, StartupError, run_node
from msfsu_common.params import NodeParameters
from msfsu_common.settings import setting
from msfsu_bringup.cli import parameter_overrides
from msfsu_bringup.playback import PlaybackSchedule
from msfsu_bringup.qos import is_latched, publisher_qos

CLOCK_TOPIC = "/clock"
TICK_S = 0.002  # scheduling granularity
ACK_TIMEOUT = Duration(seconds=5)  # at the end, wait this long for subscribers to acknowledge
STARTED_MESSAGE = "started playback"  # logged when the first message goes out (tools follow the log)


def ns_to_time(ns: int) -> TimeMsg:
    return TimeMsg(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)


@dataclass(frozen=True)
class PlayerStartup:
    """The player's read-only parameters: the bag, what of it plays, from where, and when playing starts."""

    bag: str = setting("", "rosbag2 directory to play")
    start_offset: float = setting(0.0, "skip this many seconds (at every start, loops included)", 0.0, 1e6)
    publish_clock: bool = setting(False, "publish /clock from the bag timestamps (instead of a recorded /clock)")
    topics: tuple[str, ...] = setting(("",), "topics to play (empty: all)")
    wait_for: tuple[str, ...] = setting(("",), "topics that need a subscriber to play: playing starts once each has "
                                        "one and pauses while one has none")
    wait_timeout: float = setting(10.0, "max wait for those subscribers, before or while playing: then the player "
                                  "ends with exit code 1, s", 0.0, 3600.0)
    start_delay: float = setting(0.0, "wait after subscribers are ready, s", 0.0, 3600.0)
    queue_depth: int = setting(100, "publisher queue depth", 1, 10000)


@dataclass(frozen=True)
class PlayerSettings:
    """The player's live parameters: how fast it plays and what it does at the end."""

    rate: float = setting(1.0, "playback speed factor (a new one applies from the bag time reached)", 0.01, 100.0)
    loop: bool = setting(False, "restart at the end")
    end_delay: float = setting(0.0, "stay after the last message, s", 0.0, 3600.0)


class BagPlayerNode(Node):
    def __init__(self, parameter_overrides: list[Parameter] | None = None) -> None:
        super().__init__("bag_player", parameter_overrides=parameter_overrides or [])
        self.parameters = NodeParameters(self, live=PlayerSettings, read_only=PlayerStartup, apply=self.apply_settings)
        startup = self.parameters.read_only
        bag, publish_clock = startup.bag, startup.publish_clock
        self.wait_for = [topic for topic in startup.wait_for if topic]
        if not bag:
            raise StartupError("parameter 'bag' must name a rosbag2 bag directory")
        try:
            self.reader = open_bag(Path(bag), warn=self.get_logger().warn)
        except BagError as error:
            raise StartupError(str(error)) from error
        wanted = {topic for topic in startup.topics if topic}
        self.connections = [c for c in self.reader.connections if (not wanted or c.topic in wanted)
                            and not (publish_clock and c.topic == CLOCK_TOPIC)]  # one clock source only
        if not self.connections:
            raise StartupError(f"none of the topics {sorted(wanted)} is in {bag}")
        self.publishers_by_topic = {}
        for connection in self.connections:
            if connection.topic not in self.publishers_by_topic:
                try:
                    msg_type = message_class(connection.msgtype)
                except LookupError as error:
                    raise StartupError(str(error)) from error
                qos = publisher_qos(is_latched(connection.ext.offered_qos_profiles), startup.queue_depth)
                self.publishers_by_topic[connection.topic] = self.create_publisher(msg_type, connection.topic, qos)
        published = {publisher.topic_name: publisher for publisher in self.publishers_by_topic.values()}
        # played topics: subscriptions matched with our publisher; others: subscriptions seen on the graph
        self.subscriber_counts = {topic: published[topic].get_subscription_count if topic in published
                                  else functools.partial(self.count_subscribers, topic) for topic in self.wait_for}
        self.clock_pub = self.create_publisher(Clock, CLOCK_TOPIC, 10) if publish_clock else None
        self.played = 0
        self.to_play = sum(connection.msgcount for connection in self.connections)
        self.wait_started = time.monotonic()
        self.ready_since: float | None = None
        self.paused_since = 0.0
        self.end_reached: float | None = None
        self.messages = None
        self.pending = None
        self.schedule: PlaybackSchedule | None = None  # made when playing starts
        self.create_timer(TICK_S, self.tick)
        self.get_logger().info(f"{bag}: {self.reader.message_count} messages, {len(self.publishers_by_topic)} "
                               f"topics, {self.reader.duration * 1e-9:.1f} s at rate {self.parameters.live.rate}")

    def apply_settings(self, settings: PlayerSettings) -> None:
        """New parameters in force: the rest of the bag plays at the new rate; loop and end_delay act at its end."""
        if self.schedule is not None:
            self.schedule.set_rate(settings.rate, time.monotonic_ns())

    def missing_subscribers(self) -> list[str]:
        """The `wait_for` topics that have no subscriber now."""
        return [topic for topic, count in self.subscriber_counts.items() if count() == 0]

    def subscribers_ready(self) -> bool:
        missing = self.missing_subscribers()
        if missing and time.monotonic() - self.wait_started > self.parameters.read_only.wait_timeout:
            raise NodeFailed(f"no subscriber on {', '.join(missing)} after {self.parameters.read_only.wait_timeout:g} "
                             f"s: nothing played (a managed node subscribes only once active)")
        return not missing

    def keep_playing(self, now_ns: int) -> bool:
        """While playing: pause while a `wait_for` topic has no subscriber, resume when it has one again."""
        if not self.subscriber_counts:
            return True
        missing = self.missing_subscribers()
        if not missing:
            if self.schedule.paused:
                self.get_logger().info(f"resumed: {', '.join(self.wait_for)} subscribed again")
                self.schedule.resume(now_ns)
            return True
        bag_s = (self.schedule.bag_time_ns(now_ns) - self.reader.start_time) * 1e-9
        if not self.schedule.paused:
            self.schedule.pause(now_ns)
            self.paused_since = time.monotonic()
            self.get_logger().warn(f"paused at {bag_s:.1f} s of the bag: no subscriber on {', '.join(missing)} "
                                   f"(a managed node deactivated?); playing goes on when there is one")
        elif time.monotonic() - self.paused_since > self.parameters.read_only.wait_timeout:
            raise NodeFailed(f"no subscriber on {', '.join(missing)} for {self.parameters.read_only.wait_timeout:g} s "
                             f"since {bag_s:.1f} s of the bag: stopped with {self.played} of {self.to_play} messages "
                             "played")
        return False

    def restart(self) -> None:
        start = self.reader.start_time + int(self.parameters.read_only.start_offset * 1e9)
        self.messages = self.reader.messages(connections=self.connections, start=start)
        self.pending = next(self.messages, None)
        self.schedule = PlaybackSchedule(start, time.monotonic_ns(), self.parameters.live.rate)
        self.get_logger().info(STARTED_MESSAGE)

    def tick(self) -> None:
        if self.messages is None:
            if self.ready_since is None and self.subscribers_ready():
                self.ready_since = time.monotonic()
            if self.ready_since is None or time.monotonic() - self.ready_since < self.parameters.read_only.start_delay:
                return
            self.restart()
        now = time.monotonic_ns()
        if self.pending is not None and not self.keep_playing(now):
            return
        while self.pending is not None:
            connection, bag_time, raw = self.pending
            if self.schedule.due_ns(bag_time) > now:
                return
            if self.clock_pub is not None:
                self.clock_pub.publish(Clock(clock=ns_to_time(bag_time)))
            self.publishers_by_topic[connection.topic].publish(bytes(raw))
            self.played += 1
            try:
                self.pending = next(self.messages, None)
            except BagError as error:  # a damaged chunk in a bag whose index looked intact
                self.get_logger().error(f"stopped playing: {error}")
                self.pending = None
        if self.parameters.live.loop:
            self.restart()
            return
        if self.end_reached is None:
            for publisher in self.publishers_by_topic.values():
                publisher.wait_for_all_acked(ACK_TIMEOUT)
            self.get_logger().info(f"played {self.played} messages")
            self.end_reached = time.monotonic()
        if time.monotonic() - self.end_reached >= self.parameters.live.end_delay:
            raise NodeFinished

    def destroy_node(self) -> None:
        if hasattr(self, "reader"):
            self.reader.close()
        super().destroy_node()


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("bag", nargs="?", help="rosbag2 directory")
    parser.add_argument("--rate", type=float)
    parser.add_argument("--start-offset", dest="start_offset", type=float, help="seconds to skip")
    parser.add_argument("--loop", action="store_true", default=None)
    parser.add_argument("--clock", dest="publish_clock", action="store_true", default=None)
    parser.add_argument("--topics", nargs="+")
    parser.add_argument("--wait-for", dest="wait_for", nargs="+",
                        help="topics that need a subscriber to play (playing pauses while one has none)")
    parser.add_argument("--wait-timeout", dest="wait_timeout", type=float)
    parser.add_argument("--start-delay", dest="start_delay", type=float, help="seconds to wait once subscribed")
    parser.add_argument("--end-delay", dest="end_delay", type=float, help="seconds to stay after the last message")
    return parser


def main(args=None) -> int:
    argv = sys.argv if args is None else args
    overrides = parameter_overrides(build_parser(), argv)
    return run_node(lambda: BagPlayerNode(overrides), argv)
