"""Starts the MSFSU node graph from YAML profiles; rosbag2 MCAP player and recorder."""
