"""Virtual RGB-D camera: PyBullet's TinyRenderer for the rigid scene, ``sim.raster`` for the cloth.

PyBullet's TinyRenderer (CPU, works in DIRECT mode) does draw soft bodies with their
texture on both sides, at the right depth (``tests/unit/test_sim_camera.py`` compares it
with our rasteriser), but a 640x480 frame of a room costs ~150 ms, most of it spent on
the walls and floor. The rigid scene rarely moves, so the camera renders it with
PyBullet only when a visible rigid body has moved, and draws the cloth itself
(``sim.raster``, ~30 ms) over that picture, z-buffered against its depth. Moving rigid
bodies (an occluder, a robot's gripper and arm) are drawn the same way: as
``sim.solids`` meshes that PyBullet never sees, so they do not trigger its redraw.

Images come out exact; sensor noise is added by the scene (``sim.noise``).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from ipc.messages import CameraInfo
from perception.geometry import check_transform, invert_transform, transform_points
from sim.opengl import depth_from_zbuffer, projection_matrix, view_matrix
from sim.physics import ClothPhysics
from sim.raster import Shading, rasterise_mesh
from sim.solids import SolidMesh, rasterise_solid

log = logging.getLogger(__name__)

#: ``Render.body_ids`` value where a solid drawn by ``sim.raster`` (``render(..., solids=)``) is seen
SOLID_ID = -2


@dataclass(frozen=True)
class Render:
    """One exact rendering.

    rgb : (H, W, 3) uint8 RGB
    depth_m : (H, W) float32 metres along the optical axis, 0 where nothing is drawn
    body_ids : (H, W) int32 PyBullet body id seen at each pixel (the cloth's id where
        the cloth is seen), ``SOLID_ID`` (-2) where a drawn solid is seen, -1 for none
    """

    rgb: np.ndarray
    depth_m: np.ndarray
    body_ids: np.ndarray


@dataclass(frozen=True)
class Lighting:
    """One directional light, shared by PyBullet's renderer and the cloth rasteriser.

    direction_world : (3,) direction towards the light, world frame
    ambient, diffuse, specular : weights
    """

    direction_world: tuple = (0.4, -1.0, 1.2)
    ambient: float = 0.55
    diffuse: float = 0.45
    specular: float = 0.05


class VirtualCamera:
    """A pinhole RGB-D camera at a fixed pose in a ``ClothPhysics`` world.

    camera : CameraInfo (any K without distortion; PyBullet's projection is built to match)
    T_world_cam : (4, 4) optical camera frame (x right, y down, z forward) to world
    near_m, far_m : clipping distances, metres
    lighting : Lighting
    """

    def __init__(self, camera: CameraInfo, T_world_cam: np.ndarray, near_m: float = 0.1, far_m: float = 8.0,
                 lighting: Lighting | None = None):
        if not isinstance(camera, CameraInfo):
            raise ValueError(f"VirtualCamera: expected CameraInfo, got {type(camera).__name__}")
        if camera.D.size and np.any(camera.D != 0):
            raise ValueError(f"VirtualCamera: the renderer is a pinhole; expected no distortion, got D={camera.D.tolist()}")
        self.camera = camera
        self.T_world_cam = check_transform("T_world_cam", T_world_cam)
        self.T_cam_world = invert_transform(self.T_world_cam)
        self.near_m = float(near_m)
        self.far_m = float(far_m)
        self.lighting = lighting or Lighting()
        light_cam = self.T_cam_world[:3, :3] @ np.asarray(self.lighting.direction_world, dtype=np.float64)
        self._shading = Shading(light_dir_cam=light_cam / np.linalg.norm(light_cam), ambient=self.lighting.ambient,
                                diffuse=self.lighting.diffuse, specular=self.lighting.specular)
        self._view = view_matrix(self.T_world_cam)
        self._projection = projection_matrix(camera, self.near_m, self.far_m)
        self._background: tuple | None = None  # (signature, Render) of the rigid scene

    def world_to_camera(self, points_world: np.ndarray) -> np.ndarray:
        """(N, 3) world points (metres) in the optical camera frame, (N, 3) float64."""
        return transform_points(self.T_cam_world, points_world)

    def render_rigid(self, physics: ClothPhysics) -> Render:
        """PyBullet's TinyRenderer picture of everything but the cloth."""
        p = physics.pybullet
        cam = self.camera
        light = self.lighting
        _, _, rgba, zbuffer, seg = p.getCameraImage(
            cam.width, cam.height, self._view, self._projection,
            renderer=p.ER_TINY_RENDERER,
            lightDirection=list(light.direction_world),
            lightAmbientCoeff=light.ambient,
            lightDiffuseCoeff=light.diffuse,
            lightSpecularCoeff=light.specular,
            shadow=0,
            physicsClientId=physics.client,
        )
        rgb = np.reshape(np.asarray(rgba, dtype=np.uint8), (cam.height, cam.width, 4))[:, :, :3]
        zb = np.reshape(np.asarray(zbuffer, dtype=np.float32), (cam.height, cam.width))
        ids = np.reshape(np.asarray(seg, dtype=np.int32), (cam.height, cam.width))
        # the mask packs link indices above bit 24 for multi-link bodies; ours have none
        ids = np.where(ids < 0, -1, ids & ((1 << 24) - 1)).astype(np.int32)
        return Render(np.ascontiguousarray(rgb), depth_from_zbuffer(zb, self.near_m, self.far_m), ids)

    def render(self, physics: ClothPhysics, cloth_texture_rgb: np.ndarray, solids: SolidMesh | None = None) -> Render:
        """Draw the world as it is now.

        cloth_texture_rgb : (Ht, Wt, 3) uint8 spanning the cloth's bounding box
        (``ClothMesh.texture_coords``)
        solids : rigid bodies to draw besides PyBullet's (a SolidMesh, points in the world
        frame), z-buffered with the cloth and the rigid scene; ``SOLID_ID`` in ``body_ids``
        """
        signature = physics.rigid_pose_signature()
        if self._background is None or self._background[0] != signature:
            self._background = (signature, self.render_rigid(physics))
            log.debug("rigid scene re-rendered")
        layers = [self._background[1]]
        if physics.cloth_id is not None:
            cloth = rasterise_mesh(self.world_to_camera(physics.cloth_vertices()), physics.cloth_mesh.faces,
                                   physics.cloth_mesh.texture_coords(), cloth_texture_rgb, self.camera, self._shading,
                                   near_m=self.near_m)
            layers.append((cloth, physics.cloth_id))
        if solids is not None and len(solids.faces):
            drawn = rasterise_solid(solids.transformed(self.T_cam_world), self.camera, self._shading, near_m=self.near_m)
            layers.append((drawn, SOLID_ID))
        return _composite(layers[0], layers[1:])


def _composite(background: Render, layers: list) -> Render:
    """The nearest of the background and each (MeshRaster, id) layer at every pixel."""
    if not layers:
        return background
    rgb, depth, ids = background.rgb.copy(), background.depth_m.copy(), background.body_ids.copy()
    nearest = np.where(depth > 0, depth, np.inf)
    for raster, body_id in layers:
        front = raster.mask & (raster.depth_m < nearest)
        nearest[front] = raster.depth_m[front]
        rgb[front] = raster.rgb[front]
        depth[front] = raster.depth_m[front]
        ids[front] = body_id
    return Render(rgb, depth, ids)
