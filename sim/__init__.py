"""PyBullet cloth simulation, virtual RGB-D camera and ground truth.

- ``sim.scenes``: the paper's scenes and scenes of a cloth being handled (``SCENES``,
  ``make_scene``), each a ``ClothScene`` that steps, renders ``ipc.RGBDFrame`` and gives the
  true cloth in the camera frame.
- ``sim.physics``: the PyBullet wrapper (``ClothPhysics``, ``Gripper``, ``ClothMaterial``).
- ``sim.camera``: ``VirtualCamera`` (PyBullet for the rigid scene, ``sim.raster`` for the cloth
  and for moving rigid bodies, ``sim.solids``: boxes, cylinders, spheres; ``sim.opengl``:
  PyBullet's renderer matrices made to agree with the camera's K).
- ``sim.robot_drawing``: ``GripperLook``, a parallel gripper with its wrist and arm to draw.
- ``sim.noise``: depth/colour sensor noise; ``sim.ground_truth``: the accuracy metric, and
  what an occluder hides.
- ``sim.evaluation``: tracker runs on recorded scenes, their scores (also while handled),
  the CPD peer and figures.
- ``sim.cloth_mesh``, ``sim.textures``: cloth meshes and textures generated in code.
- ``sim.scene``: the one scene interface; ``sim.frame_source``: a scene as a frame source;
  ``sim.recorder``: a scene written as a sequence folder with ground truth.
- ``sim.laundry``: the laundry-grasping task (scene, controller policy, judge);
  ``sim.grasp_execution``: a GraspPlan executed by a simulated gripper.

PyBullet is imported only when a ``ClothPhysics`` is created, so the pure parts
(meshes, noise, ground truth) work without it. How a new scene joins them:
docs/architecture.md, "Adding a scene".
"""

from sim.camera import Lighting, Render, VirtualCamera
from sim.cloth_mesh import (
    ClothMesh,
    TShirtShape,
    edge_strain,
    rectangle_cloth,
    tshirt_cloth,
)
from sim.ground_truth import (
    bind_to_surface,
    error_summary,
    surface_points,
    vertex_errors,
)
from sim.noise import DepthNoiseModel, add_colour_noise, add_depth_noise
from sim.opengl import projection_matrix, view_matrix
from sim.physics import ClothMaterial, ClothPhysics, Gripper
from sim.scenes import SCENES, ClothScene, SceneSpec, kinect_camera, make_scene
from sim.textures import plain_texture, poster_texture

__all__ = [
    "SCENES",
    "ClothMaterial",
    "ClothMesh",
    "ClothPhysics",
    "ClothScene",
    "DepthNoiseModel",
    "Gripper",
    "Lighting",
    "Render",
    "SceneSpec",
    "TShirtShape",
    "VirtualCamera",
    "add_colour_noise",
    "add_depth_noise",
    "bind_to_surface",
    "edge_strain",
    "error_summary",
    "kinect_camera",
    "make_scene",
    "plain_texture",
    "poster_texture",
    "projection_matrix",
    "rectangle_cloth",
    "surface_points",
    "tshirt_cloth",
    "vertex_errors",
    "view_matrix",
]
