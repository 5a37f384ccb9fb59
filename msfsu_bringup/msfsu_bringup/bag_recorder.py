"""bag_recorder: records chosen topics into a rosbag2 MCAP bag (metadata.yaml + .mcap).

Subscribes with raw=True and writes the received CDR bytes as they are, stamped with the
receive time on the node clock (sim time under use_sim_time), like `ros2 bag record`. Topics
are discovered as they appear; each subscription copies its publishers' reliability/durability.
On SIGINT/SIGTERM the node is destroyed in order and the writer closed: every message received
is in the bag, which `ros2 bag info` and Foxglove open. Every `flush_period` the MCAP chunk being
filled is closed and handed to the OS, so a recorder killed outright (SIGKILL, out of memory) leaves
a bag that `bag_player`, training and evaluation still read up to its last flush (bag_io.open_bag).
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import dataclass
from pathlib import Path

from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

from msfsu_common.bag_io import flush_to_disk, mcap_writer, msfsu_typestore
from msfsu_common.message_types import message_class
from msfsu_common.node_runner import StartupError, run_node
from msfsu_common.params import NodeParameters, retime
from msfsu_common.settings import setting
from msfsu_bringup.cli import parameter_overrides
from msfsu_bringup.qos import bag_qos

IGNORED_TOPICS = {"/rosout", "/parameter_events"}


@dataclass(frozen=True)
class RecorderStartup:
    """The recorder's read-only parameters: the bag it writes and which topics go into it."""

    output: str = setting("", "bag directory to create (must not exist)")
    topics: tuple[str, ...] = setting(("",), "topics to record")
    all: bool = setting(False, "record every topic that appears")


@dataclass(frozen=True)
class RecorderSettings:
    """The recorder's live parameters: how often it looks for topics and writes the bag out."""

    discovery_period: float = setting(0.2, "how often to look for new topics, s", 0.01, 60.0)
    flush_period: float = setting(1.0, "how often the bag is written out (at most this much is lost if the recorder "
                                  "is killed), s", 0.01, 3600.0)


class BagRecorderNode(Node):
    def __init__(self, parameter_overrides: list[Parameter] | None = None) -> None:
        super().__init__("bag_recorder", parameter_overrides=parameter_overrides or [])
        self.parameters = NodeParameters(self, live=RecorderSettings, read_only=RecorderStartup,
                                         apply=self.apply_settings)
        startup, settings = self.parameters.read_only, self.parameters.live
        output = startup.output
        self.wanted = {topic for topic in startup.topics if topic}
        self.record_all = startup.all
        if not output or Path(output).exists():
            raise StartupError(f"parameter 'output' must name a bag directory that does not exist yet: '{output}'")
        if not self.wanted and not self.record_all:
            raise StartupError("give topics to record (topics:=[...]) or all:=true")
        self.typestore = msfsu_typestore()
        self.writer = mcap_writer(output)
        self.writer.open()
        self.connections = {}
        self.recorded = 0
        self.discovery_timer = self.create_timer(settings.discovery_period, self.discover)
        self.flush_timer = self.create_timer(settings.flush_period, lambda: flush_to_disk(self.writer))
        self.discover()
        self.get_logger().info(f"recording into {output}")

    def apply_settings(self, settings: RecorderSettings) -> None:
        """New parameters in force: the next discovery and flush come a new period from now."""
        retime(self.discovery_timer, settings.discovery_period)
        retime(self.flush_timer, settings.flush_period)

    def discover(self) -> None:
        for topic, types in self.get_topic_names_and_types():
            if topic in self.connections or topic in IGNORED_TOPICS:
                continue
            if not (self.record_all or topic in self.wanted):
                continue
            self.subscribe(topic, types[0])

    def subscribe(self, topic: str, type_name: str) -> None:
        publishers = self.get_publishers_info_by_topic(topic)
        if not publishers:
            return
        reliable = all(p.qos_profile.reliability == ReliabilityPolicy.RELIABLE for p in publishers)
        latched = all(p.qos_profile.durability == DurabilityPolicy.TRANSIENT_LOCAL for p in publishers)
        qos = QoSProfile(
            depth=100,
            reliability=ReliabilityPolicy.RELIABLE if reliable else ReliabilityPolicy.BEST_EFFORT,
            durability=DurabilityPolicy.TRANSIENT_LOCAL if latched else DurabilityPolicy.VOLATILE,
        )
        try:
            msg_type = message_class(type_name)
            connection = self.writer.add_connection(topic, type_name, typestore=self.typestore,
                                                    offered_qos_profiles=[bag_qos(latched)])
        except (LookupError, KeyError) as error:
            self.get_logger().error(f"cannot record {topic} [{type_name}]: {error}")
            self.connections[topic] = None
            return
        self.connections[topic] = connection
        self.create_subscription(msg_type, topic, lambda raw, c=connection: self.write(c, raw), qos, raw=True)
        self.get_logger().info(f"subscribed {topic} [{type_name}]")

    def write(self, connection, raw: bytes) -> None:
        self.writer.write(connection, self.get_clock().now().nanoseconds, raw)
        self.recorded += 1

    def destroy_node(self) -> None:
        self.writer.close()
        self.get_logger().info(f"closed bag with {self.recorded} messages")
        super().destroy_node()


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("output", nargs="?", help="bag directory to create")
    parser.add_argument("--topics", nargs="+")
    parser.add_argument("-a", "--all", action="store_true", default=None)
    parser.add_argument("--flush-period", dest="flush_period", type=float, help="seconds between writes to disk")
    return parser


def main(args=None) -> int:
    argv = sys.argv if args is None else args
    overrides = parameter_overrides(build_parser(), argv)
    return run_node(lambda: BagRecorderNode(overrides), argv)
