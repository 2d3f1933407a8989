"""The perception service's tracker parameters: which ones travel, their ranges, and the work budgets.

A ``SetParametersRequest`` may set every bool, int, float or str field of
``perception.tracker.TrackerConfig`` (``tracker_parameters``); ``apply_parameters`` checks
each value's type and ``PARAMETER_RANGES`` range, all or nothing, and ``check_work``
refuses a configuration whose mesh or solver work would exceed the budgets
(``MAX_MESH_VERTICES``, ``MAX_VERTEX_STEPS``), so that one frame's work, which control
requests wait for, stays bounded (docs/protocol.md, "Parameters"). Pure: no sockets.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

from perception.tracker import TrackerConfig, config_with

#: Value types a tracker parameter must have to be read and set over the wire.
WIRE_TYPES = (bool, int, float, str)


#: Most vertices a mesh may have: a finer spacing is refused when the current object (or,
#: before any mesh, the area seen in the last frame) would need more. With the paper's
#: preset a 5,500-vertex mesh took 0.25 s a frame and 0.4 s to build on two cores, so a
#: control request waiting for that frame is still answered within the 1 s of docs/protocol.md.
MAX_MESH_VERTICES = 5000

#: Most lattice points laid over an object when a mesh is built (``object_lattice_bound``),
#: an upper bound of its vertices: a compact object (a flat rectangle of cloth) keeps about
#: three quarters of them, so this admits the vertex budget for it and bounds every other.
LATTICE_BUDGET = 2 * MAX_MESH_VERTICES

#: Most solver work per frame, in vertex-steps: vertices x iterations x conjugate-gradient
#: steps per iteration (1 for the semi-implicit solver), for tracking (``max_iterations``) and
#: for the initialisation (``init_iterations``). The paper's preset on a 5,000-vertex mesh.
MAX_VERTEX_STEPS = 5000 * 10 * 8


@dataclass(frozen=True)
class Range:
    """Allowed values of a numerical parameter: from ``lo`` (excluded when ``lo_open``) to
    ``hi``, and 0 too when ``or_zero`` (a parameter for which 0 means "choose it")."""

    lo: float
    hi: float
    lo_open: bool = False
    or_zero: bool = False

    def __contains__(self, value) -> bool:
        if self.or_zero and value == 0:
            return True
        return (self.lo < value if self.lo_open else self.lo <= value) and value <= self.hi

    def __str__(self) -> str:
        return f"{'0 or ' if self.or_zero else ''}{'(' if self.lo_open else '['}{self.lo:g}, {self.hi:g}]"


#: The range of every numerical parameter a SetParametersRequest may set: TrackerConfig's own
#: lower bounds, and upper bounds that keep the solver's numbers finite and one frame's work
#: bounded (a frame is tracked while control requests wait).
PARAMETER_RANGES = {
    "spacing_m": Range(0.005, 1.0, or_zero=True),
    "target_vertices": Range(3, MAX_MESH_VERTICES),
    "lambda_c": Range(0.0, 100.0),
    "lambda_d": Range(0.0, 100.0),
    "lambda_b": Range(0.0, 100.0),
    "lambda_m": Range(0.0, 100.0),
    "lambda_l": Range(0.0, 100.0),
    "lambda_h": Range(0.0, 1000.0),
    "lambda_o": Range(0.0, 100.0),
    "lambda_f": Range(0.0, 100.0),
    "tether_slack": Range(0.0, 1.0),
    "alpha": Range(1e-3, 1e3),
    "max_iterations": Range(1, 100),
    "cg_iterations": Range(1, 100),
    "tolerance_m": Range(0.0, 1.0, lo_open=True),
    "min_predicted_decrease": Range(0.0, 1.0),
    "max_features": Range(1, 2000),
    "min_descriptor_features": Range(0, 2000),
    "min_texture_snr": Range(0.0, 1000.0),
    "anchor_points": Range(0, 2000),
    "match_gate_px": Range(0.0, 1000.0, lo_open=True),
    "match_keep_fraction": Range(0.0, 1.0, lo_open=True),
    "depth_window_px": Range(1, 31),
    "depth_outlier_m": Range(0.0, 10.0, lo_open=True),
    "occlusion_margin_m": Range(0.0, 10.0, lo_open=True),
    "unknown_occluder_m": Range(0.0, 1.0),
    "boundary_gate_m": Range(0.0, 10.0, lo_open=True),
    "velocity_prediction": Range(0.0, 2.0),
    "init_iterations": Range(0, 100),
    "confidence_tol_m": Range(0.0, 10.0, lo_open=True),
    "carried_tol_m": Range(0.0, 10.0, lo_open=True),
    "lost_confidence": Range(0.0, 1.0),
    "reacquire_every": Range(0, 1000),
}


def tracker_parameters(config: TrackerConfig) -> dict:
    """Every TrackerConfig field whose value is a bool, int, float or str, with its value:
    the parameters a SetParametersRequest may change (tuples and nested configs may not)."""
    return {f.name: getattr(config, f.name) for f in dataclasses.fields(config)
            if isinstance(getattr(config, f.name), WIRE_TYPES)}


def apply_parameters(config: TrackerConfig, parameters: dict) -> TrackerConfig:
    """A copy of ``config`` with ``parameters`` (name -> value) applied, all or nothing.

    A value must have its parameter's type (an int is accepted for a float parameter) and
    lie in its ``PARAMETER_RANGES`` range. The budgets, which depend on the object, are
    ``check_work``'s.
    raises ValueError naming the unknown names, or the first parameter that cannot be set
    over the wire, or the first value of the wrong type or out of its range
    """
    if any(name not in TrackerConfig.__dataclass_fields__ for name in parameters):
        config_with(config, **parameters)  # raises ValueError naming every unknown name
    settable = tracker_parameters(config)
    changes = {}
    for name, value in parameters.items():
        if name not in settable:
            raise ValueError(f"tracker parameter {name!r} cannot be set over the wire (not a bool, int, float or str)")
        current = settable[name]
        if isinstance(current, bool):
            ok = isinstance(value, bool)
        elif isinstance(current, int):
            ok = isinstance(value, int) and not isinstance(value, bool)
        elif isinstance(current, float):
            ok = isinstance(value, (int, float)) and not isinstance(value, bool)
            value = float(value) if ok else value
        else:
            ok = isinstance(value, str)
        if not ok:
            raise ValueError(f"tracker parameter {name!r}: expected {type(current).__name__}, "
                             f"got {type(value).__name__} {value!r}")
        allowed = PARAMETER_RANGES.get(name)
        if allowed is not None and value not in allowed:
            raise ValueError(f"tracker parameter {name!r}: expected a value in {allowed}, got {value!r}")
        changes[name] = value
    return config_with(config, **changes)


def check_work(config: TrackerConfig, n_vertices: int | None) -> None:
    """Refuse a configuration whose mesh of ``n_vertices`` (None: not known) would exceed
    ``MAX_MESH_VERTICES``, or whose solver work per frame would exceed ``MAX_VERTEX_STEPS``.

    raises ValueError naming the parameter and the largest or smallest value allowed
    """
    cg = config.cg_iterations if config.solver == "conjugate" else 1
    steps = max(config.max_iterations, config.init_iterations) * cg
    if n_vertices is None:
        return
    if n_vertices > MAX_MESH_VERTICES:
        raise ValueError(f"tracker parameter 'spacing_m': {config.spacing_m:g} m gives about {n_vertices} vertices on the "
                         f"object, over the budget of {MAX_MESH_VERTICES}; expected a spacing of at least "
                         f"{config.spacing_m * math.sqrt(n_vertices / MAX_MESH_VERTICES):.4g} m")
    if n_vertices * steps > MAX_VERTEX_STEPS:
        raise ValueError(f"tracker parameters 'max_iterations', 'init_iterations' and 'cg_iterations': {n_vertices} vertices x "
                         f"{steps} steps is {n_vertices * steps} vertex-steps a frame, over the budget of {MAX_VERTEX_STEPS}; "
                         f"expected at most {MAX_VERTEX_STEPS // max(n_vertices, 1)} steps (iterations x cg_iterations)")
