"""Perception: the RGB-D mesh tracker of Willimon et al. (2013) and its adapters.

Public API::

    from perception import MeshTracker, TrackerConfig, rectangle_mesh
"""

from perception.mesh import CanonicalMesh, rectangle_mesh
from perception.tracker import MeshTracker, TrackerConfig, TrackingError

__all__ = ["CanonicalMesh", "MeshTracker", "TrackerConfig", "TrackingError", "rectangle_mesh"]
