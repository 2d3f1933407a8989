"""Grasp-point selection on an estimated cloth mesh, and the planner service.

The selection core is pure NumPy/SciPy: it takes ``ipc.messages.MeshEstimate``
(and optionally the ``RGBDFrame`` it came from) and returns ``GraspPlan``
messages. Corners and boundary points come from the geometry of the canonical
(rest) mesh, never from fixed vertex ids. A cloth hanging from one point is grasped
at its lowest point instead (``lowest_point_grasp``, on the observed points; from the
side, ``from_the_side``, where a hand cannot come up from below). A cloth
held by one corner is grasped next at a corner adjacent to it along the canonical
outline (``adjacent_corners``), to stretch the edge between them.
"""

from grasping._adjacent import AdjacentCornersResult, adjacent_corners
from grasping._hanging import from_the_side, lowest_point_grasp
from grasping._outline import corner_angles, find_corners
from grasping._planner import GraspPlanner, GraspPlannerConfig, GraspResult, GraspTerms, plan_grasps
from grasping._visibility import depth_agrees

__all__ = ["AdjacentCornersResult", "GraspPlanner", "GraspPlannerConfig", "GraspResult", "GraspTerms",
           "adjacent_corners", "corner_angles", "depth_agrees", "find_corners", "from_the_side", "lowest_point_grasp",
           "plan_grasps"]
