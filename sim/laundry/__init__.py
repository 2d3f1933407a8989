"""The laundry-grasping task: a towel or T-shirt on a table (or held up by a corner), the
robot's controller policy and the judge of its grasp.

- ``spec``: ``LaundrySpec``, pure data drawn from a seed by ``laundry_spec``;
- ``scene``: ``LaundryScene``, which builds the PyBullet world from a spec, drops and
  settles the cloth, renders noisy RGB-D frames and answers ground-truth questions (where
  the true corners and the outline of the cloth are); a ``sim.scene.Scene``;
- ``truth``: the true corners and outline in material coordinates (pure);
- ``segment``: the cloth found against a picture of the empty table (the robot's view);
- ``controller``: which grasp the robot executes (``lowest_point_when_held``,
  ``best_candidate``, ``default_controller``);
- ``judge``: success by ground truth (``judge`` for one grasp, ``judge_unfold`` for two
  corners that share an edge, held apart);
- ``unfold``: the unfolding robot's motions (lift, second corner, stretch) and its arms' mounts;
- ``pictures``: the plan drawn on its frame, the grasp before and after the lift.

``launch_scripts.trial_runner`` runs a trial with these through the ZeroMQ services;
``sim.grasp_execution`` executes the chosen grasp.

What a seed draws (``laundry_spec``):

- cloth: a towel (rectangle 0.35-0.60 m by 0.30-0.50 m) or a T-shirt (the default
  ``TShirtShape`` scaled by 0.60-0.85), printed (poster texture) or plain coloured;
- initial state (``INITIAL_STATES``): ``flat`` (laid flat at a random yaw and dropped
  from a few centimetres), ``crumpled`` (dropped edge first from 10-25 cm in a pose
  tilted by 35-75 degrees; it lands shifted and creased, mostly spread: PyBullet's
  cloth has little bending stiffness), ``folded`` (a straight fold: the part of the
  cloth beyond a random row or column of its vertices is turned over before the
  drop), or ``held`` (hanging from a holder that clamps one true
  corner, its lowest point above the table; the holder is a visible box around that
  corner, which it hides as a hand would; the cloth falls into its folds for 5 s and is
  then brought to rest, as air drag, which PyBullet lacks, would do); a task may draw
  among some of them (the unfold task: ``TABLE_STATES``, the cloth on the table), and a
  seed whose state is among them draws the same scene either way;
- the cloth's layers collide with each other (``ClothMaterial.self_collision``): a fold
  or a crumple stacks its layers, each 12 mm (twice the collision margin) above the one
  below, rather than letting them pass into one plane, so a fold stands thicker than
  one layer as a real one does;
- table: top 0.70-0.78 m above the floor, 1.2 m x 0.8 m, neutral grey;
- camera: 1.0-1.3 m from the cloth, 50-70 degrees above the horizontal, azimuth within
  20 degrees of the table's front (-y), aim jittered by a few centimetres; Kinect-like
  intrinsics, sensor noise on by default (``sim.noise``). The "room" view (``view="room"``,
  the unfold task) stands 1.55-1.75 m back, 18-28 degrees up, to see the space above the
  table too; it is drawn last, so the rest of the scene is the same in both views.

Ground truth (material coordinates ``uv_m`` of ``sim.cloth_mesh``, metres on the flat
cloth): the true corners (a towel's four corners; a T-shirt's hem corners and the two
corners of each sleeve end, taken from the ``TShirtShape`` construction, not from mesh
indices) and the material outline (the mesh's boundary edges).

World frame: z up, floor top at z = 0, the table centred on the origin. Camera frame:
OpenCV optical; ``T_world_cam`` (4, 4) maps camera points to the world.
The same seed gives the same scene and the same frames; noise on or off does not
change the scene (independent random streams, as ``sim.scenes``).
"""

from sim.laundry.controller import TURNS_RAD, View, best_candidate, default_controller, lowest_point_when_held
from sim.laundry.judge import TOLERANCE_M, Judgement, judge
from sim.laundry.scene import LaundryScene
from sim.laundry.segment import cloth_points, cloth_seen, mask_from_reference, seen_cloth_points
from sim.laundry.spec import (
    CLOTH_KINDS,
    CLOTH_SPACING_M,
    INITIAL_STATES,
    STATE_PROBABILITIES,
    TABLE_HALF_XY_M,
    TABLE_STATES,
    LaundrySpec,
    laundry_spec,
)
from sim.laundry.truth import distance_to_segments, nearest_corner, rectangle_corners_uv, tshirt_corners_uv

__all__ = [
    "CLOTH_KINDS",
    "CLOTH_SPACING_M",
    "INITIAL_STATES",
    "STATE_PROBABILITIES",
    "TABLE_HALF_XY_M",
    "TABLE_STATES",
    "TOLERANCE_M",
    "TURNS_RAD",
    "Judgement",
    "LaundryScene",
    "LaundrySpec",
    "View",
    "best_candidate",
    "cloth_points",
    "cloth_seen",
    "default_controller",
    "distance_to_segments",
    "judge",
    "laundry_spec",
    "lowest_point_when_held",
    "mask_from_reference",
    "nearest_corner",
    "rectangle_corners_uv",
    "seen_cloth_points",
    "tshirt_corners_uv",
]
