"""QoS from the profiles stored in rosbag2 bags."""

from __future__ import annotations

from collections.abc import Sequence

from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from rosbags.interfaces import Qos, QosDurability, QosHistory, QosLiveliness, QosReliability, QosTime


def is_latched(profiles: Sequence[Qos]) -> bool:
    """A topic recorded from transient-local publishers (e.g. the route) is replayed latched."""
    return any(profile.durability == QosDurability.TRANSIENT_LOCAL for profile in profiles)


def bag_qos(latched: bool) -> Qos:
    """The profile stored in a bag for a publisher (what `ros2 bag record` writes)."""
    zero = QosTime(sec=0, nsec=0)
    return Qos(
        history=QosHistory.KEEP_LAST,
        depth=1 if latched else 10,
        reliability=QosReliability.RELIABLE,
        durability=QosDurability.TRANSIENT_LOCAL if latched else QosDurability.VOLATILE,
        deadline=zero, lifespan=zero, liveliness=QosLiveliness.AUTOMATIC, liveliness_lease_duration=zero,
        avoid_ros_namespace_conventions=False,
    )


def publisher_qos(latched: bool, depth: int) -> QoSProfile:
    """Reliable; latched topics keep their last message for late subscribers."""
    return QoSProfile(
        depth=1 if latched else depth,
        reliability=ReliabilityPolicy.RELIABLE,
        durability=DurabilityPolicy.TRANSIENT_LOCAL if latched else DurabilityPolicy.VOLATILE,
    )
