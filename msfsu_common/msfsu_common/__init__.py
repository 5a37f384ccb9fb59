"""Shared ROS-side helpers of the MSFSU stack: ROS environment, road options, topic names, image conversion."""
