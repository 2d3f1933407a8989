"""Perception: the RGB-D mesh tracker of Willimon et al. (2013) and its adapters.

Public API::

    from perception import MeshTracker, TrackerConfig, rectangle_mesh

The names are loaded on first use, so that ``perception.geometry`` (the geometry every
package shares) can be imported without the tracker and its dependencies. Where each
part of the package stands: docs/architecture.md.
"""

import importlib

_PUBLIC = {
    "CanonicalMesh": "perception.mesh",
    "rectangle_mesh": "perception.mesh",
    "MeshTracker": "perception.tracker",
    "TrackerConfig": "perception.tracker",
    "TrackingError": "perception.tracker",
}

__all__ = sorted(_PUBLIC)


def __getattr__(name: str):
    if name not in _PUBLIC:
        raise AttributeError(f"module 'perception' has no attribute {name!r}")
    return getattr(importlib.import_module(_PUBLIC[name]), name)
