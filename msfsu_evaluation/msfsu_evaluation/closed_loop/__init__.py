"""Closed-loop benchmark (`msfsu-benchmark`): suites and routes, episode rules and metrics (ROS-free),
the simulator worker with its ROS adapter, and reports."""
