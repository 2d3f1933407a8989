"""Figures of tracking runs: error over time, and 3D views of estimates beside the input cloud.

Each function draws into a new matplotlib figure and saves it as a PNG at ``path``. The
figures are drawn without pyplot, so importing this module selects no backend and
opens no window.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
from matplotlib.figure import Figure
from mpl_toolkits.mplot3d.art3d import Line3DCollection

from perception.geometry import crop_intrinsics, rays, unique_edges
from perception.overlay import draw_mesh

# (elevation, azimuth) of matplotlib's 3D camera for the paper's Fig. 5 views, with the
# optical frame re-labelled so that "up" is -y and the viewer looks along +z.
VIEWS = {"front": (0, -90), "top": (90, -90), "45° pan": (0, -45)}


def _to_plot(points_cam: np.ndarray) -> np.ndarray:
    """Optical (x right, y down, z forward) to plot axes (x right, y forward, z up)."""
    return np.column_stack([points_cam[:, 0], points_cam[:, 2], -points_cam[:, 1]])


def error_over_time(path: Path, title: str, series: dict[str, np.ndarray], fps: float = 30.0) -> None:
    """series : label -> (T, N) metres; plots each label's mean (solid) and 95th percentile (dotted)."""
    fig = Figure(figsize=(7, 3.6))
    ax = fig.subplots()
    for i, (label, err) in enumerate(series.items()):
        t = np.arange(err.shape[0]) / fps
        colour = f"C{i}"
        ax.plot(t, 1000 * err.mean(axis=1), color=colour, label=f"{label} mean")
        ax.plot(t, 1000 * np.percentile(err, 95, axis=1), color=colour, linestyle=":", label=f"{label} p95")
    ax.set_xlabel("time (s)")
    ax.set_ylabel("vertex error (mm)")
    ax.set_title(title)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, ncol=2)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def error_with_occlusion(path: Path, title: str, runs: dict[str, dict], hidden_s: np.ndarray,
                         hidden_fraction: np.ndarray, wrong_mm: float, confident: float,
                         shaded: str | None = None, error_label: str = "mean vertex error (mm)") -> None:
    """Error and confidence over time, with the occluder's passage shaded.

    runs : label -> {"time_s": (T,), "mean_mm": (T,), "confidence": (T,), "lost": (T,) bool}
    hidden_s, hidden_fraction : (S,) times and the fraction of the true cloth hidden by the
        occluder then, drawn as a grey band on both panels (darker = more hidden)
    wrong_mm, confident : the thresholds of a wrong and of a confident estimate, as dashed lines
    shaded, error_label : what the grey band (None: the cloth hidden, by how much at most) and
        the error axis show, for the axes' labels
    """
    fig = Figure(figsize=(7.5, 5.2))
    ax_err, ax_conf = fig.subplots(2, 1, sharex=True, height_ratios=(3, 2))
    peak = max(float(np.max(hidden_fraction)), 1e-9) if len(hidden_fraction) else 1.0
    step = float(np.median(np.diff(hidden_s))) if len(hidden_s) > 1 else 1.0 / 30.0
    for ax in (ax_err, ax_conf):
        for t, f in zip(hidden_s, hidden_fraction):
            if f > 0:
                ax.axvspan(t - 0.5 * step, t + 0.5 * step, color="0.3", alpha=0.08 + 0.25 * f / peak, lw=0)
    for i, (label, run) in enumerate(runs.items()):
        colour = f"C{i}"
        t, err, conf, lost = (np.asarray(run[k]) for k in ("time_s", "mean_mm", "confidence", "lost"))
        ax_err.plot(t, err, color=colour, label=label, marker="." if len(t) < 60 else None, ms=3)
        ax_conf.plot(t, conf, color=colour)
        if lost.any():
            ax_err.plot(t[lost], err[lost], "x", color=colour, ms=5)
    ax_err.axhline(wrong_mm, color="k", linestyle="--", lw=0.8)
    ax_conf.axhline(confident, color="k", linestyle="--", lw=0.8)
    ax_err.set_ylabel(error_label)
    ax_err.set_yscale("symlog", linthresh=10.0)
    peaks = [np.nanmax(np.asarray(run["mean_mm"], float)) for run in runs.values()
             if np.isfinite(np.asarray(run["mean_mm"], float)).any()]
    ax_err.set_ylim(0.0, 1.5 * max([wrong_mm, *peaks]))  # every run in sight, the worst too
    ax_conf.set_ylabel("confidence")
    ax_conf.set_ylim(-0.02, 1.02)
    shaded = shaded or f"cloth hidden by the occluder (up to {100 * peak:.0f} %)"
    ax_conf.set_xlabel(f"time (s); shaded: {shaded}; x: flagged lost")
    ax_err.set_title(title, fontsize=10)
    for ax in (ax_err, ax_conf):
        ax.grid(alpha=0.3)
    ax_err.legend(fontsize=7, ncol=2)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def cloud_of(frame, mask: np.ndarray, max_points: int = 4000, rng=None) -> tuple[np.ndarray, np.ndarray]:
    """The object's coloured point cloud: points (P, 3) camera frame and colours (P, 3) in [0, 1]."""
    rng = rng if rng is not None else np.random.default_rng(0)
    d = np.nan_to_num(frame.depth_m, nan=0.0)
    ys, xs = np.nonzero(mask & (d > 0))
    if len(xs) > max_points:
        pick = rng.choice(len(xs), max_points, replace=False)
        ys, xs = ys[pick], xs[pick]
    pts = rays(np.column_stack([xs, ys]).astype(float), frame.camera.K) * d[ys, xs, None]
    return pts, frame.rgb[ys, xs] / 255.0


def views(path: Path, title: str, cloud: tuple[np.ndarray, np.ndarray], meshes: dict[str, tuple]) -> None:
    """Rows: front, top, 45° pan; columns: the input cloud, then each mesh (vertices, faces)."""
    cols = 1 + len(meshes)
    fig = Figure(figsize=(3.0 * cols, 8.4))
    pts, colours = cloud
    P = _to_plot(pts)
    lo, hi = P.min(axis=0), P.max(axis=0)
    centre, half = (lo + hi) / 2, (hi - lo).max() / 2 * 1.1
    for r, (view, (elev, azim)) in enumerate(VIEWS.items()):
        for c in range(cols):
            ax = fig.add_subplot(3, cols, r * cols + c + 1, projection="3d")
            if c == 0:
                ax.scatter(P[:, 0], P[:, 1], P[:, 2], c=colours, s=0.5, depthshade=False)
                name = "input point cloud"
            else:
                name, (V, faces) = list(meshes.items())[c - 1]
                Vp = _to_plot(V)
                e = unique_edges(faces)
                ax.add_collection3d(Line3DCollection(np.stack([Vp[e[:, 0]], Vp[e[:, 1]]], axis=1), colors="k",
                                                     linewidths=0.3))
            for setter, k in ((ax.set_xlim, 0), (ax.set_ylim, 1), (ax.set_zlim, 2)):
                setter(centre[k] - half, centre[k] + half)
            ax.view_init(elev=elev, azim=azim)
            ax.set_box_aspect((1, 1, 1))
            ax.set_axis_off()
            if r == 0:
                ax.set_title(name, fontsize=9)
        fig.text(0.005, 1 - (r + 0.5) / 3, view, rotation=90, va="center", fontsize=9)
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=100)


def overlay_strip(path: Path, frames: list, estimates: list, picks: list[int], region: np.ndarray | None = None,
                  margin_px: int = 40) -> None:
    """The mesh drawn over the RGB frames ``picks`` side by side (the paper's Fig. 6, top row).

    region : (H, W) bool, optional; each tile shows only its bounding box plus ``margin_px``
    """
    H, W = frames[picks[0]].rgb.shape[:2]
    y0, y1, x0, x1 = 0, H, 0, W
    if region is not None and np.any(region):
        rows, cols = np.nonzero(region)
        y0, y1 = max(rows.min() - margin_px, 0), min(rows.max() + margin_px + 1, H)
        x0, x1 = max(cols.min() - margin_px, 0), min(cols.max() + margin_px + 1, W)
    tiles = []
    for i in picks:
        K = crop_intrinsics(frames[i].camera.K, x0, y0)
        tiles.append(draw_mesh(np.ascontiguousarray(frames[i].rgb[y0:y1, x0:x1]), estimates[i], K))
    h = 240
    tiles = [cv2.resize(t, (int(t.shape[1] * h / t.shape[0]), h), interpolation=cv2.INTER_AREA) for t in tiles]
    strip = np.concatenate(tiles, axis=1)
    cv2.imwrite(str(path), cv2.cvtColor(strip, cv2.COLOR_RGB2BGR))
