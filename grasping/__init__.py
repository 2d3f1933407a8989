"""Grasp-point selection on an estimated cloth mesh, and the planner service.

The selection core is pure NumPy/SciPy: it takes ``ipc.messages.MeshEstimate``
(and optionally the ``RGBDFrame`` it came from) and returns ``GraspPlan``
messages. Corners and boundary points come from the geometry of the canonical
(rest) mesh, never from fixed vertex ids.
"""

from grasping._outline import find_corners
from grasping._planner import GraspPlanner, GraspPlannerConfig, GraspResult, GraspTerms, plan_grasps

__all__ = ["GraspPlanner", "GraspPlannerConfig", "GraspResult", "GraspTerms", "find_corners", "plan_grasps"]
