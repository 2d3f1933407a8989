"""The geometry every package shares: camera model, rigid transforms, input checks, mesh topology.

Pure NumPy (and OpenCV for lens distortion) on arrays, in the toolkit's conventions:
metres, radians, the OpenCV optical camera frame (x right, y down, z forward), pixel
(u, v) = (column, row) with pixel centres at integers, ``T_a_b`` (4, 4) mapping frame b to
frame a, quaternions (x, y, z, w). It sits just above ``ipc`` and below everything else:
it imports nothing from ``perception`` outside this package, nor ``sim``, ``grasping`` or
``launch_scripts``. docs/architecture.md shows where it stands.

- camera: ``project``, ``rays``, ``backproject``, ``ray_lengths``, ``pixel_index``,
  ``crop_intrinsics``, ``Undistorter``
- transforms: ``transform_points``, ``invert_transform``, ``look_at``,
  ``rotation_about_axis``, ``frames_from_z_and_x``, ``frame_along``,
  ``quaternion_xyzw_from_matrix``
- checks: ``check_points``, ``check_ids``, ``check_vector``, ``check_positive``,
  ``check_transform``
- topology: ``directed_edges``, ``unique_edges``, ``edge_length_graph``, ``boundary_half_edges``,
  ``boundary_chains``, ``boundary_edges``, ``boundary_vertices``, ``face_normals``, ``face_areas``,
  ``vertex_normals``
"""

from perception.geometry._camera import (
    Undistorter,
    backproject,
    crop_intrinsics,
    lens_coefficients,
    pixel_index,
    project,
    ray_lengths,
    rays,
    same_optics,
)
from perception.geometry._checks import (
    check_ids,
    check_points,
    check_positive,
    check_transform,
    check_vector,
)
from perception.geometry._topology import (
    boundary_chains,
    boundary_edges,
    boundary_half_edges,
    boundary_vertices,
    directed_edges,
    edge_length_graph,
    face_areas,
    face_normals,
    unique_edges,
    vertex_normals,
)
from perception.geometry._transforms import (
    frame_along,
    frames_from_z_and_x,
    invert_transform,
    look_at,
    quaternion_xyzw_from_matrix,
    rigid_transform,
    rotation_about_axis,
    transform_points,
)

__all__ = [
    "Undistorter",
    "backproject",
    "boundary_chains",
    "boundary_edges",
    "boundary_half_edges",
    "boundary_vertices",
    "check_ids",
    "check_points",
    "check_positive",
    "check_transform",
    "check_vector",
    "crop_intrinsics",
    "directed_edges",
    "edge_length_graph",
    "face_areas",
    "face_normals",
    "frame_along",
    "frames_from_z_and_x",
    "invert_transform",
    "lens_coefficients",
    "look_at",
    "pixel_index",
    "project",
    "quaternion_xyzw_from_matrix",
    "ray_lengths",
    "rays",
    "rigid_transform",
    "rotation_about_axis",
    "same_optics",
    "transform_points",
    "unique_edges",
    "vertex_normals",
]
