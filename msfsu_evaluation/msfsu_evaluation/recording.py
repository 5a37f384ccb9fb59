"""What the node graph published during a replay, read back from the recorder's bag.

The recorder runs on the wall clock, so a message's log time is when the recorder received it.
Recording the camera RGB beside the outputs gives each frame two receipts on one clock in one
process: RGB in, DrivingAction out. Their difference is the graph's latency for that frame
(decode, pairing, preprocessing, network, publish and delivery); the RGB's own delivery time,
which reaches perception at the same moment, is the only part it leaves out. The perception
node's diagnostics report latency too, but on the bag's clock (steps of the replayed /clock)
and as rolling percentiles, not per frame.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from msfsu_common import topics
from msfsu_common.bag_io import msfsu_typestore, open_bag
from msfsu_common.image_codec import decode_mono8
from msfsu_common.message_types import stamp_ns

PERCEPTION_STATUS = "msfsu/perception"
RECORDED_TOPICS = (topics.DRIVING_ACTION, topics.NETWORK_ACTION, topics.AEB_INTERVENTION, topics.SEGMENTATION,
                   topics.VEHICLE_CONTROL, topics.DIAGNOSTICS, topics.RGB)


@dataclass(frozen=True)
class RecordedOutputs:
    """DrivingActions in receipt order, with the receipts of the frames they answer."""

    action_stamps_ns: np.ndarray  # (M,) int64 header stamp = camera frame stamp
    steer: np.ndarray  # (M,) float32
    target_speed: np.ndarray  # (M,) float32 m/s
    command: np.ndarray  # (M,) uint8 branch the network used
    action_received_ns: np.ndarray  # (M,) int64 wall clock
    frame_received_ns: dict[int, int]  # camera frame stamp -> first wall-clock receipt of its RGB
    control_stamps_ns: set[int]  # header stamps of the VehicleControls (= the answered action's stamp)
    perception_diagnostics: dict[str, str]  # the last status the perception node published
    # the emergency brake, where the graph had one (its decision per frame stamp, from /msfsu/aeb/intervention: the
    # frames it capped or braked, and the one it let go on); None: no brake in the graph
    interventions: dict[int, str] | None = None


def read_outputs(recording: Path) -> RecordedOutputs:
    """The recorded outputs. With an emergency brake in the graph, the actions are the network's own
    (/msfsu/network/driving_action: what the expert's labels score), received when the brake sent them on to the
    control (the graph's latency, the brake's hop included)."""
    store = msfsu_typestore()
    sent: list[tuple[int, float, float, int, int]] = []  # /msfsu/driving_action: what the control got
    network: dict[int, tuple[float, float, int]] = {}  # the network's own, with a brake in the graph
    interventions: dict[int, str] = {}
    frame_received: dict[int, int] = {}
    control_stamps: set[int] = set()
    diagnostics: dict[str, str] = {}
    wanted = (topics.DRIVING_ACTION, topics.NETWORK_ACTION, topics.AEB_INTERVENTION, topics.VEHICLE_CONTROL,
              topics.DIAGNOSTICS, topics.RGB)
    with open_bag(recording) as reader:
        connections = [c for c in reader.connections if c.topic in wanted]
        brake_in_graph = any(c.topic == topics.NETWORK_ACTION for c in connections)
        for connection, received_ns, raw in reader.messages(connections):
            msg = store.deserialize_cdr(raw, connection.msgtype)
            if connection.topic == topics.VEHICLE_CONTROL:
                control_stamps.add(stamp_ns(msg.header))
            elif connection.topic == topics.DRIVING_ACTION:
                sent.append((stamp_ns(msg.header), msg.steer, msg.target_speed, msg.command, received_ns))
            elif connection.topic == topics.NETWORK_ACTION:
                network[stamp_ns(msg.header)] = (msg.steer, msg.target_speed, msg.command)
            elif connection.topic == topics.AEB_INTERVENTION:
                interventions[stamp_ns(msg.header)] = msg.decision
            elif connection.topic == topics.RGB:
                frame_received.setdefault(stamp_ns(msg.header), received_ns)
            else:
                for status in msg.status:
                    if status.name == PERCEPTION_STATUS:
                        diagnostics = {pair.key: pair.value for pair in status.values}
    actions = [(stamp, *network[stamp], received) for stamp, _, _, _, received in sent if stamp in network] \
        if brake_in_graph else sent
    columns = list(zip(*actions)) if actions else [()] * 5
    return RecordedOutputs(
        action_stamps_ns=np.array(columns[0], np.int64),
        steer=np.array(columns[1], np.float32),
        target_speed=np.array(columns[2], np.float32),
        command=np.array(columns[3], np.uint8),
        action_received_ns=np.array(columns[4], np.int64),
        frame_received_ns=frame_received,
        control_stamps_ns=control_stamps,
        perception_diagnostics=diagnostics,
        interventions=interventions if brake_in_graph else None,
    )


def iter_segmentation(recording: Path) -> Iterator[tuple[int, np.ndarray]]:
    """(frame stamp, (h, w) uint8 predicted class ids) per recorded segmentation, one at a time."""
    store = msfsu_typestore()
    with open_bag(recording) as reader:
        connections = [c for c in reader.connections if c.topic == topics.SEGMENTATION]
        for connection, _, raw in reader.messages(connections):
            msg = store.deserialize_cdr(raw, connection.msgtype)
            yield stamp_ns(msg.header), decode_mono8(msg)
