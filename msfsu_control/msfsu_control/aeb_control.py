"""aeb_control: the aeb and control nodes composed in one process, one executor (ROS 2 composition for rclpy).

The emergency brake's action goes to the control without waking a second process; each node is what it is on its
own (its name, parameters, topics, diagnostics). Parameters for one of them carry its name:
`aeb_control --ros-args -p aeb:predict_crossing:=false -p control:max_steer_rate:=2.0`; a parameter without a name
goes to both. Why it exists and what it measures: docs/realtime.md ("With the emergency brake").
"""

from __future__ import annotations

from msfsu_common.node_runner import run_nodes
from msfsu_control.aeb_node import AebNode
from msfsu_control.control_node import ControlNode


def main(args=None) -> int:
    return run_nodes([AebNode, ControlNode], args)


if __name__ == "__main__":
    raise SystemExit(main())
