"""Figures of tracking runs (sim.evaluation.figures): PNG files, drawn without pyplot."""

import subprocess
import sys

import cv2
import numpy as np

from sim.evaluation.figures import error_over_time, views


def test_figures_are_png_files(tmp_path):
    rng = np.random.default_rng(0)
    error_over_time(tmp_path / "err.png", "errors", {"tracker": rng.uniform(0, 0.01, (30, 20))})
    faces = np.array([[0, 1, 2], [1, 3, 2]])
    square = np.array([[0.0, 0.0, 1.0], [0.1, 0.0, 1.0], [0.0, 0.1, 1.0], [0.1, 0.1, 1.0]])
    views(tmp_path / "views.png", "views", (square, np.full((4, 3), 0.5)), {"mesh": (square, faces)})
    for name in ("err.png", "views.png"):
        img = cv2.imread(str(tmp_path / name))
        assert img is not None and img.shape[0] > 100 and img.std() > 0


def test_importing_the_figures_selects_no_backend():
    code = "import sys, sim.evaluation.figures; print('matplotlib.pyplot' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"
