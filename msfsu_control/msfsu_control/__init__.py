"""Longitudinal PID control node and route (navigation command) node."""
