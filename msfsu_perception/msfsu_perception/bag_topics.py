"""Which topics of a bag make a training sample (defaults: the stack's topic names)."""

from __future__ import annotations

from dataclasses import dataclass

from msfsu_common import topics


@dataclass(frozen=True)
class BagTopics:
    rgb: str = topics.RGB  # sensor_msgs/Image rgb8 / bgr8 / bgra8
    depth: str = topics.DEPTH  # sensor_msgs/Image 32FC1 metres (16UC1 mm accepted)
    semantic_ids: str = topics.SEMANTIC_IDS  # sensor_msgs/Image mono8, class ids 0..4
    expert_action: str = topics.EXPERT_ACTION  # msfsu_interfaces/DrivingAction, stamp = camera frame
    navigation_command: str = topics.NAVIGATION_COMMAND  # msfsu_interfaces/NavigationCommand
    noise_injection: str = topics.NOISE_INJECTION  # std_msgs/Bool, latest value applies
    # on-policy bags (optional): focus frames (bag_index.FocusConfig)
    network_driving: str = topics.NETWORK_DRIVING  # std_msgs/Bool per frame, the network drove it
    network_action: str = topics.DRIVING_ACTION  # msfsu_interfaces/DrivingAction the network asked for, stamp = frame
    expert_limited_by: str = topics.EXPERT_LIMITED_BY  # std_msgs/String per frame, what held the expert's label
    clock: str = topics.CLOCK  # rosgraph_msgs/Clock (written by the synthetic bags, not read)
