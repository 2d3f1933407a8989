"""Tracker evaluation on simulated scenes: the runs, their scores against ground truth, the peer, figures.

It sits above both ``perception`` (the tracker it runs) and the rest of ``sim`` (the
scenes it records); nothing below imports it (docs/architecture.md).

- ``runs``: ``SceneRecording`` (a scene's frames with the true cloth, made once and
  tracked by any number of variants), ``record_scene``, ``track_recording``,
  ``cpd_recording``, ``TrackRun`` and the paper's ablations;
- ``handled``: the scores of tracking a cloth while it is handled (an occluder in front);
- ``cpd_peer``: pycpd's deformable CPD, the speed and accuracy peer of the tracker;
- ``figures``: error over time, 3D views, overlay strips (PNG files).

The accuracy metric itself is ``sim.ground_truth``'s.
"""

from sim.evaluation.runs import ABLATIONS, SceneRecording, TrackRun, cpd_recording, record_scene, track_recording

__all__ = ["ABLATIONS", "SceneRecording", "TrackRun", "cpd_recording", "record_scene", "track_recording"]
