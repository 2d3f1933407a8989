"""PyBullet physics wrapper: a deformable world with one cloth, rigid boxes and grippers.

This is the only module that steps PyBullet. It owns a DIRECT connection (no GUI), so
any number of worlds can live in one process. Accessors return NumPy arrays in the
world frame (z up, metres); scene logic (``sim.scenes``) stays outside.

Cloth model: PyBullet's mass-spring soft body. Its deformable solver adds the spring
forces explicitly (only damping is implicit), so a spring stiffer than the node masses
and time step allow explodes (measured: see ``ClothMaterial``), and a soft one lets the
cloth stretch like rubber.
``ClothMaterial.spring_stiffness`` therefore derives the stiffness from the node mass
and time step (``stiffness_number`` = omega * dt of one spring on one node), and
``sim.cloth_mesh.edge_strain`` measures the stretch that results.
"""

from __future__ import annotations

import logging
import os
import tempfile
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from perception.geometry import check_vector
from sim.cloth_mesh import ClothMesh, write_obj

log = logging.getLogger(__name__)


def _pybullet():
    # imported here so that the pure modules of sim (meshes, noise, ground truth) and
    # their users never need PyBullet
    import pybullet

    return pybullet


@dataclass(frozen=True)
class ClothMaterial:
    """Mass-spring parameters of a cloth.

    mass_per_area_kg_m2 : areal density (printed poster paper ~0.2, T-shirt ~0.18,
        towel ~0.4)
    stiffness_number : omega * dt of one stretch spring acting on one node; the spring
        constant is ``node_mass * (stiffness_number / dt) ** 2`` (N/m). Measured at
        dt = 1/240 s (2.5 cm poster grid, 3 cm T-shirt): hanging and moved freely, 2.5
        explodes with ``damping_number`` 2 and holds with 4, 2.0 holds; dragged over a
        chair's backrest (contact), 2.0 explodes on 3 of 4 seeds, 1.5 holds on 8 of 8.
        The default 1.5 leaves a mean edge strain of ~0.8 % hanging by two corners
        (``sim.cloth_mesh.edge_strain``; test_sim_physics bounds it).
    bending_ratio : bending-spring constant relative to the stretch springs
    damping_number : damping constant of each spring as ``node_mass / dt * damping_number``
        (N s/m), acting along the spring: damps stretching of neighbours, not swinging
        or bending of the whole cloth
    friction : contact friction coefficient with rigid bodies
    collision_margin_m : contact thickness around the cloth
    self_collision : layers of the cloth collide with each other, so a fold or a crumple
        stacks one layer on another (2 * ``collision_margin_m`` apart) instead of letting
        them pass through each other into one plane, where depth cannot tell a fold
        from a single layer; PyBullet's default is off
    """

    mass_per_area_kg_m2: float = 0.2
    stiffness_number: float = 1.5
    bending_ratio: float = 0.05
    damping_number: float = 2.0
    friction: float = 0.8
    collision_margin_m: float = 0.006
    self_collision: bool = False

    def node_mass_kg(self, mesh: ClothMesh) -> float:
        """Mean mass of one node of ``mesh`` (kg)."""
        return self.total_mass_kg(mesh) / mesh.n_vertices

    def total_mass_kg(self, mesh: ClothMesh) -> float:
        """Mass of the whole cloth (kg): density times the flat mesh's area."""
        uv = mesh.uv_m
        d1 = uv[mesh.faces[:, 1]] - uv[mesh.faces[:, 0]]
        d2 = uv[mesh.faces[:, 2]] - uv[mesh.faces[:, 0]]
        area = 0.5 * np.abs(d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0]).sum()
        return float(self.mass_per_area_kg_m2 * area)

    def spring_stiffness(self, mesh: ClothMesh, timestep_s: float) -> float:
        """Stretch spring constant (N/m) for ``mesh`` simulated at ``timestep_s``."""
        return self.node_mass_kg(mesh) * (self.stiffness_number / timestep_s) ** 2

    def damping(self, mesh: ClothMesh, timestep_s: float) -> float:
        """Spring damping constant (N s/m) for ``mesh`` simulated at ``timestep_s``."""
        return self.node_mass_kg(mesh) / timestep_s * self.damping_number


def _check_timestep(where: str, timestep_s) -> float:
    if not 0 < timestep_s <= 0.02:
        raise ValueError(f"{where}: expected 0 < timestep_s <= 0.02, got {timestep_s}")
    return float(timestep_s)


def _check_quat(value, name: str) -> np.ndarray:
    q = check_vector(name, value, size=4)
    norm = np.linalg.norm(q)
    if abs(norm - 1.0) > 1e-6:
        raise ValueError(f"{name}: expected a unit quaternion (x, y, z, w), got norm {norm:.6g}")
    return q


def slerp(q0: np.ndarray, q1: np.ndarray, t: float) -> np.ndarray:
    """Spherical interpolation of unit quaternions (x, y, z, w), t in [0, 1]."""
    q0 = np.asarray(q0, dtype=np.float64)
    q1 = np.asarray(q1, dtype=np.float64)
    dot = float(q0 @ q1)
    if dot < 0:  # take the short way round
        q1, dot = -q1, -dot
    if dot > 0.9995:
        q = q0 + t * (q1 - q0)
        return q / np.linalg.norm(q)
    theta = np.arccos(dot)
    return (np.sin((1 - t) * theta) * q0 + np.sin(t * theta) * q1) / np.sin(theta)


def _mass_springs(mesh: ClothMesh, stiffness_n_m: float, bending_ratio: float) -> tuple[np.ndarray, np.ndarray]:
    """The springs PyBullet's mass-spring cloth puts between nodes: (S, 2) int64 node pairs
    and (S,) float64 spring constants (N/m). A stretch spring along each mesh edge, and a
    bending spring (``bending_ratio`` as stiff) between every two nodes two edges apart."""
    edges = mesh.edges()
    n = mesh.n_vertices
    ones = np.ones(len(edges))
    links = sp.coo_matrix((ones, (edges[:, 0], edges[:, 1])), shape=(n, n)).tocsr()
    links = links + links.T
    two = sp.triu(links @ links, k=1).tocsr()
    two = (two - two.multiply(links)).tocoo()  # less the pairs a stretch spring already joins
    two.eliminate_zeros()
    bending = np.stack([two.row, two.col], axis=1).astype(np.int64)
    constants = np.concatenate([np.full(len(edges), stiffness_n_m), np.full(len(bending), stiffness_n_m * bending_ratio)])
    return np.concatenate([edges.astype(np.int64), bending]), constants


class Gripper:
    """A kinematic holder: a massless body moved by pose that anchors cloth nodes.

    It emulates a robot gripper (or a hand): ``close_on(nodes)`` pins those cloth nodes
    to it where they are now, so they follow its position and orientation; ``open()``
    releases them. ``move_to`` sets the pose it reaches at the end of the next
    ``ClothPhysics.advance`` (straight line, slerped orientation). The body has no
    collision shape, so the cloth never collides with it. ``cloth_force_n()`` is what a
    force sensor at its wrist reads.

    Create it with ``ClothPhysics.add_gripper``.
    """

    def __init__(self, physics: ClothPhysics, body_id: int, position: np.ndarray, quat_xyzw: np.ndarray):
        self._physics = physics
        self.body_id = body_id
        self._position = position
        self._quat = quat_xyzw
        self._target = (position, quat_xyzw)
        self._anchors: list[int] = []
        self._held: list[int] = []

    @property
    def position(self) -> np.ndarray:
        """(3,) float64 world position, metres."""
        return self._position.copy()

    @property
    def quat_xyzw(self) -> np.ndarray:
        """(4,) float64 world orientation (x, y, z, w)."""
        return self._quat.copy()

    @property
    def held_nodes(self) -> np.ndarray:
        """(K,) int64 ids of the cloth nodes anchored to the gripper."""
        return np.array(self._held, dtype=np.int64)

    @property
    def is_closed(self) -> bool:
        return bool(self._held)

    def cloth_force_n(self) -> np.ndarray:
        """(3,) float64 newtons, world frame: the force the cloth pulls the gripper with, as a
        force sensor at its wrist reads it (less the gripper's own weight).

        The cloth's springs from the nodes the gripper holds to the nodes it does not (their
        extension beyond the rest length times the spring constant, along the spring), plus
        the held nodes' weight; the springs' damping is left out (nothing at rest, little at
        a slow pull). Hanging at rest, it reads the cloth's weight. Zero when it holds nothing.
        """
        physics = self._physics
        if not self._held:
            return np.zeros(3)
        held = np.zeros(physics.cloth_mesh.n_vertices, dtype=bool)
        held[self._held] = True
        springs = physics.cloth_springs
        crossing = held[springs[:, 0]] != held[springs[:, 1]]
        a, b = springs[crossing, 0], springs[crossing, 1]
        inner, outer = np.where(held[a], a, b), np.where(held[a], b, a)
        V = physics.cloth_vertices()
        d = V[outer] - V[inner]
        length = np.maximum(np.linalg.norm(d, axis=1), 1e-12)
        pull = physics.cloth_spring_n_m[crossing] * (length - physics.cloth_spring_rest_m[crossing]) / length
        return (pull[:, None] * d).sum(axis=0) + len(self._held) * physics.cloth_node_mass_kg * physics.gravity_m_s2

    def move_to(self, position, quat_xyzw=None) -> None:
        """Pose to reach by the end of the next ``ClothPhysics.advance``.

        position : (3,) float, metres, world frame; quat_xyzw : (4,) unit quaternion,
        default the current orientation
        """
        pos = check_vector("position", position)
        quat = self._quat if quat_xyzw is None else _check_quat(quat_xyzw, "quat_xyzw")
        self._target = (pos, quat)

    def close_on(self, nodes) -> None:
        """Anchor cloth nodes to the gripper at their current positions.

        nodes : (K,) int ids of cloth nodes, e.g. those between the fingers:
            ``ClothPhysics.nodes_near(fingertip_centre, half_opening_m)``; nodes already
            held are skipped
        """
        if self._physics.cloth_id is None:
            raise ValueError("Gripper.close_on: no cloth in this world (call add_cloth first)")
        ids = np.unique(np.asarray(nodes, dtype=np.int64).ravel())
        n = self._physics.cloth_mesh.n_vertices
        if ids.size == 0:
            raise ValueError("Gripper.close_on: expected at least one node id, got none")
        if ids.min() < 0 or ids.max() >= n:
            raise ValueError(f"Gripper.close_on: node ids outside [0, {n})")
        p = self._physics.pybullet
        for node in ids:
            if node in self._held:
                continue
            anchor = p.createSoftBodyAnchor(self._physics.cloth_id, int(node), self.body_id, -1,
                                            physicsClientId=self._physics.client)
            self._anchors.append(anchor)
            self._held.append(int(node))
        log.debug("gripper %d holds %d nodes", self.body_id, len(self._held))

    def open(self) -> None:
        """Release every anchored node."""
        p = self._physics.pybullet
        for anchor in self._anchors:
            p.removeConstraint(anchor, physicsClientId=self._physics.client)
        self._anchors.clear()
        self._held.clear()

    def _set_pose(self, position: np.ndarray, quat: np.ndarray) -> None:
        self._physics.pybullet.resetBasePositionAndOrientation(
            self.body_id, position.tolist(), quat.tolist(), physicsClientId=self._physics.client)
        self._position, self._quat = position, quat

    def _interpolated(self, start: tuple, t: float) -> tuple[np.ndarray, np.ndarray]:
        (p0, q0), (p1, q1) = start, self._target
        return p0 + t * (p1 - p0), slerp(q0, q1, t)


class ClothPhysics:
    """A PyBullet deformable world (DIRECT mode) holding one cloth.

    timestep_s : physics step in seconds; ``advance`` runs whole steps
    gravity_m_s2 : (3,) world gravity

    Use as a context manager, or call ``close()``: it disconnects PyBullet and removes
    the temporary mesh file.
    """

    def __init__(self, timestep_s: float = 1.0 / 240.0, gravity_m_s2=(0.0, 0.0, -9.81)):
        self.timestep_s = _check_timestep("ClothPhysics", timestep_s)
        self.pybullet = _pybullet()
        p = self.pybullet
        self.client = p.connect(p.DIRECT)
        p.resetSimulation(p.RESET_USE_DEFORMABLE_WORLD, physicsClientId=self.client)
        self.gravity_m_s2 = check_vector("gravity_m_s2", gravity_m_s2)
        p.setGravity(*self.gravity_m_s2, physicsClientId=self.client)
        p.setTimeStep(self.timestep_s, physicsClientId=self.client)
        self._tmp = tempfile.TemporaryDirectory(prefix="clothkit_sim_")
        self.time_s = 0.0
        self.cloth_id: int | None = None
        self.cloth_mesh: ClothMesh | None = None
        self.grippers: list[Gripper] = []

    def set_timestep(self, timestep_s: float) -> None:
        """Step by ``timestep_s`` from now on. The cloth keeps the spring constants it was
        added with (``add_cloth`` derives them from the step then): a shorter step
        integrates the same cloth more finely."""
        self.timestep_s = _check_timestep("set_timestep", timestep_s)
        self.pybullet.setTimeStep(self.timestep_s, physicsClientId=self.client)

    def __enter__(self) -> ClothPhysics:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        """Disconnect from PyBullet and delete the temporary files (idempotent)."""
        if self.client is not None and self.client >= 0:
            self.pybullet.disconnect(physicsClientId=self.client)
            self.client = None
        self._tmp.cleanup()

    def add_box(self, half_extents_m, position, quat_xyzw=(0.0, 0.0, 0.0, 1.0),
                rgba=(0.6, 0.6, 0.6, 1.0)) -> int:
        """A static, collidable box (floor, wall, chair part); returns its body id.

        half_extents_m : (3,) metres; position : (3,) metres, world; rgba : 4 floats in [0, 1]
        """
        p = self.pybullet
        half = check_vector("half_extents_m", half_extents_m)
        if np.any(half <= 0):
            raise ValueError(f"add_box: half extents must be positive, got {half.tolist()}")
        pos = check_vector("position", position)
        quat = _check_quat(quat_xyzw, "quat_xyzw")
        col = p.createCollisionShape(p.GEOM_BOX, halfExtents=half.tolist(), physicsClientId=self.client)
        vis = p.createVisualShape(p.GEOM_BOX, halfExtents=half.tolist(), rgbaColor=list(rgba),
                                  physicsClientId=self.client)
        return p.createMultiBody(0.0, col, vis, pos.tolist(), quat.tolist(), physicsClientId=self.client)

    def add_cloth(self, mesh: ClothMesh, vertices_world: np.ndarray, material: ClothMaterial) -> int:
        """Load the cloth as a PyBullet mass-spring soft body; returns its body id.

        mesh : ClothMesh (topology; rest lengths come from ``vertices_world``)
        vertices_world : (V, 3) float, metres, initial (unstretched) node positions
        material : ClothMaterial

        The soft body is made invisible to PyBullet's renderer: ``sim.camera`` draws the
        cloth itself over PyBullet's picture of the rigid scene.
        """
        if self.cloth_id is not None:
            raise ValueError("add_cloth: this world already has a cloth")
        p = self.pybullet
        verts = np.asarray(vertices_world, dtype=np.float64)
        if verts.shape != (mesh.n_vertices, 3):
            raise ValueError(f"add_cloth: expected vertices_world of shape ({mesh.n_vertices}, 3), got {verts.shape}")
        obj_path = os.path.join(self._tmp.name, "cloth.obj")
        write_obj(obj_path, verts, mesh.faces, mesh.texture_coords())
        stiffness = material.spring_stiffness(mesh, self.timestep_s)
        self.cloth_id = p.loadSoftBody(
            obj_path,
            basePosition=[0.0, 0.0, 0.0],
            mass=material.total_mass_kg(mesh),
            collisionMargin=material.collision_margin_m,
            useMassSpring=1,
            useBendingSprings=1,
            springElasticStiffness=stiffness,
            springBendingStiffness=stiffness * material.bending_ratio,
            springDampingStiffness=material.damping(mesh, self.timestep_s),
            useSelfCollision=int(material.self_collision),
            frictionCoeff=material.friction,
            physicsClientId=self.client,
        )
        # alpha 0: the TinyRenderer skips the soft body entirely (see sim.camera)
        p.changeVisualShape(self.cloth_id, -1, rgbaColor=[1.0, 1.0, 1.0, 0.0], physicsClientId=self.client)
        self.cloth_mesh = mesh
        # what the grippers' force sensors need (Gripper.cloth_force_n): PyBullet's springs,
        # resting at the lengths the cloth was loaded with
        self.cloth_springs, self.cloth_spring_n_m = _mass_springs(mesh, stiffness, material.bending_ratio)
        self.cloth_spring_rest_m = np.linalg.norm(verts[self.cloth_springs[:, 0]] - verts[self.cloth_springs[:, 1]],
                                                  axis=1)
        self.cloth_node_mass_kg = material.node_mass_kg(mesh)
        loaded = self.cloth_vertices()
        if loaded.shape != verts.shape or np.abs(loaded - verts).max() > 1e-4:
            raise RuntimeError("add_cloth: PyBullet reordered or moved the cloth's nodes")
        log.info("cloth: %d nodes, %.3f kg, spring %.1f N/m", mesh.n_vertices, material.total_mass_kg(mesh), stiffness)
        return self.cloth_id

    def rigid_pose_signature(self) -> tuple:
        """Poses of the visible rigid bodies, to tell whether the rigid scene changed."""
        p = self.pybullet
        out = []
        for i in range(p.getNumBodies(physicsClientId=self.client)):
            body = p.getBodyUniqueId(i, physicsClientId=self.client)
            if body == self.cloth_id or not p.getVisualShapeData(body, physicsClientId=self.client):
                continue
            pos, quat = p.getBasePositionAndOrientation(body, physicsClientId=self.client)
            out.append((body, tuple(np.round(pos, 6)), tuple(np.round(quat, 6))))
        return tuple(out)

    def cloth_vertices(self) -> np.ndarray:
        """(V, 3) float64 world positions of the cloth nodes, metres, in mesh vertex order."""
        if self.cloth_id is None:
            raise ValueError("cloth_vertices: no cloth in this world (call add_cloth first)")
        p = self.pybullet
        _, verts = p.getMeshData(self.cloth_id, -1, flags=p.MESH_DATA_SIMULATION_MESH, physicsClientId=self.client)
        return np.asarray(verts, dtype=np.float64)

    def nodes_near(self, point, radius_m: float) -> np.ndarray:
        """(K,) int64 ids of cloth nodes within ``radius_m`` of ``point`` (3,), world metres."""
        centre = check_vector("point", point)
        d = np.linalg.norm(self.cloth_vertices() - centre, axis=1)
        return np.nonzero(d <= radius_m)[0].astype(np.int64)

    def add_gripper(self, position, quat_xyzw=(0.0, 0.0, 0.0, 1.0), visual_half_extents_m=None,
                    rgba=(0.2, 0.2, 0.2, 1.0)) -> Gripper:
        """A kinematic gripper at a world pose; invisible unless ``visual_half_extents_m`` (3,) is given."""
        p = self.pybullet
        pos = check_vector("position", position)
        quat = _check_quat(quat_xyzw, "quat_xyzw")
        vis = -1
        if visual_half_extents_m is not None:
            half = check_vector("visual_half_extents_m", visual_half_extents_m)
            vis = p.createVisualShape(p.GEOM_BOX, halfExtents=half.tolist(), rgbaColor=list(rgba),
                                      physicsClientId=self.client)
        body = p.createMultiBody(0.0, -1, vis, pos.tolist(), quat.tolist(), physicsClientId=self.client)
        gripper = Gripper(self, body, pos, quat)
        self.grippers.append(gripper)
        return gripper

    def stop_cloth(self) -> None:
        """Set the velocity of every cloth node to zero; positions and anchors stay.

        PyBullet's ``resetBaseVelocity`` on a soft body sets each node's velocity to the
        given angular velocity about the centre of mass plus the mean velocity, and then
        shifts them all by the change of the mean (``btSoftBody::setAngularVelocity`` and
        ``setLinearVelocity``): with both zero, every node stops.
        """
        if self.cloth_id is None:
            raise ValueError("stop_cloth: no cloth in this world (call add_cloth first)")
        self.pybullet.resetBaseVelocity(self.cloth_id, [0.0, 0.0, 0.0], [0.0, 0.0, 0.0], physicsClientId=self.client)

    def settle_to_rest(self, duration_s: float) -> int:
        """Step for ``duration_s`` (whole steps) with kinetic damping; returns how often the cloth was stopped.

        PyBullet's cloth has no air drag and damps its springs only along them, so a cloth
        hanging in the air swings and flaps for tens of seconds, where a real one comes to
        rest in a second or two. Kinetic damping (dynamic relaxation) brings it to the
        static equilibrium near its current shape: the cloth moves freely, and whenever
        its kinetic energy (equal node masses) stops growing, every node is stopped
        (``stop_cloth``). Grippers hold still (pending ``move_to`` targets wait for the next
        ``advance``). Use it for a scene's settling, not during a task: it is no physics.
        """
        n = round(float(duration_s) / self.timestep_s)
        if n < 0:
            raise ValueError(f"settle_to_rest: expected a non-negative duration, got {duration_s}")
        p = self.pybullet
        previous = self.cloth_vertices()
        energy_before, stops = 0.0, 0
        for _ in range(n):
            p.stepSimulation(physicsClientId=self.client)
            now = self.cloth_vertices()
            energy = float(np.sum((now - previous) ** 2))
            previous = now
            if energy < energy_before:  # past a peak of the kinetic energy
                self.stop_cloth()
                stops, energy = stops + 1, 0.0
            energy_before = energy
        self.time_s += n * self.timestep_s
        log.debug("cloth settled to rest in %.2f s (stopped %d times)", n * self.timestep_s, stops)
        return stops

    def advance(self, duration_s: float) -> None:
        """Step the world for ``duration_s`` (rounded to whole steps), moving each gripper
        along a straight line to its ``move_to`` target, reached on the last step."""
        n = round(float(duration_s) / self.timestep_s)
        if n < 0:
            raise ValueError(f"advance: expected a non-negative duration, got {duration_s}")
        p = self.pybullet
        starts = [(g.position, g.quat_xyzw) for g in self.grippers]
        for k in range(1, n + 1):
            for gripper, start in zip(self.grippers, starts):
                gripper._set_pose(*gripper._interpolated(start, k / n))
            p.stepSimulation(physicsClientId=self.client)
        self.time_s += n * self.timestep_s
