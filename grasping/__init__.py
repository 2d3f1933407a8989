"""Grasp-point selection on an estimated cloth mesh, and the planner service."""
