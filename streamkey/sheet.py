"""Pictures of a clip's keyposes: the contact sheet and the driving-signal plot.

`contact_sheet` draws every keypose as a stick figure, in frame order, left to right in rows
(the thumbnail application of Halit & Capin, §4.5: a clip summarised by its salient poses).
Each pose is shown in its own body-aligned view (root translation and heading removed), so
the sheet compares postures, not where the actor stood. `plot_signals` draws the driving
signals of a clip (the body-frame speed of Miura eq. 2-3 and the saliency candidate weight
of Halit §3.1.4) with one marker row per method.

matplotlib is an optional extra (`pip install 'streamkey[plot]'`); without it both functions
raise a `UsageError` saying so. The projections (`keypose_points`) need numpy only.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from .errors import UsageError
from .features import Features, compute_features
from .keyframes import Keyframes
from .kinematics import forward_kinematics
from .motion import Motion
from .roles import MIURA_ROLES
from .signal import hp_filter, hp_lambda

__all__ = ["contact_sheet", "plot_signals", "keypose_points", "driving_signals", "SheetResult",
           "FIGURE_COLOR", "VIEWS", "require_matplotlib"]

FIGURE_COLOR = "#1f4e8c"   # every stick figure of a sheet, nothing else, has this colour
VIEWS = {"front": 0.0, "three-quarter": 45.0, "side": 90.0}   # azimuth from the front, degrees
METHOD_COLORS = {"saliency": "#d62728", "speed": "#1f77b4", "simplify": "#2ca02c",
                 "uniform": "#7f7f7f", "decimate": "#ff7f0e", "optimal": "#bcbd22"}


@dataclass
class SheetResult:
    """What a picture holds: its path, the frames drawn (file numbering), the figure count."""

    path: Path
    frames: list[int]
    figures: int


def require_matplotlib() -> Any:
    """Import matplotlib with the file-only Agg backend, or explain how to install it."""
    try:
        import matplotlib
    except ImportError:
        raise UsageError("pictures need matplotlib: install streamkey[plot] "
                         "(pip install 'streamkey[plot]')") from None
    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt

    return plt


def keypose_points(motion: Motion, frames: np.ndarray | list[int],
                   view: str = "three-quarter") -> np.ndarray:
    """2-D points (k, points, 2) of the poses at `frames`, body-aligned, in body heights.

    Root translation is removed (x/z; y kept so the feet stay on the ground line), the pose
    is turned so the hips face +z, then seen from `view` (orthographic).
    """
    if view not in VIEWS:
        raise UsageError(f"view must be one of {', '.join(VIEWS)}, got {view!r}")
    frames = np.asarray(frames, dtype=np.int64)
    if len(frames) and (frames.min() < 0 or frames.max() >= motion.n_frames):
        raise UsageError(f"frames must lie in 0..{motion.n_frames - 1}")
    fk = forward_kinematics(motion.skeleton, motion.channels[frames])
    pos = fk.positions - fk.positions[:, :1] * np.array([1.0, 0.0, 1.0])
    fwd = fk.root_rotation[:, :, 2]  # the root's local +z axis in the world
    yaw = np.arctan2(fwd[:, 0], fwd[:, 2]) - np.deg2rad(VIEWS[view])
    c, s = np.cos(yaw)[:, None], np.sin(yaw)[:, None]
    x = c * pos[..., 0] - s * pos[..., 2]   # rotate about y by -yaw, then look along -z
    from .kinematics import body_height

    height = body_height(motion.skeleton) or 1.0
    return np.stack([x, pos[..., 1]], axis=-1) / height


def _bones(motion: Motion) -> list[tuple[int, int]]:
    skel = motion.skeleton
    bones = [(j, p) for j, p in enumerate(skel.parents) if p >= 0]
    bones += [(skel.n_joints + i, j) for i, j in enumerate(sorted(skel.end_sites))]
    return bones


def contact_sheet(motion: Motion, keys: Keyframes | list[int] | np.ndarray,
                  path: str | os.PathLike[str], columns: int = 10,
                  view: str = "three-quarter", title: str | None = None,
                  cell_inches: float = 1.3, dpi: int = 100) -> SheetResult:
    """Write a PNG of the keyposes as stick figures in frame order; returns what it drew."""
    frames = np.unique(np.asarray(keys.frames if isinstance(keys, Keyframes) else keys,
                                  dtype=np.int64))
    if len(frames) == 0:
        raise UsageError("contact sheet: no keyframes to draw")
    if columns < 1:
        raise UsageError("contact sheet: columns must be at least 1")
    plt = require_matplotlib()
    pts = keypose_points(motion, frames, view)
    from matplotlib.collections import LineCollection

    bones = np.array(_bones(motion))
    cols = min(columns, len(frames))
    rows = -(-len(frames) // cols)
    fig, axes = plt.subplots(rows, cols, figsize=(cols * cell_inches, rows * cell_inches * 1.35
                                                  + (0.3 if title else 0)),
                             squeeze=False)
    half = max(float(np.abs(pts[..., 0]).max()), 0.3) * 1.05
    lo, hi = float(pts[..., 1].min()), float(pts[..., 1].max())
    for ax in axes.ravel():
        ax.set_axis_off()
    for i, frame in enumerate(frames):
        ax = axes[i // cols, i % cols]
        ax.add_collection(LineCollection(pts[i][bones], colors=FIGURE_COLOR, linewidths=1.6,
                                         capstyle="round"))
        ax.set_xlim(-half, half)
        ax.set_ylim(lo - 0.05, hi + 0.05)
        ax.set_aspect("equal")
        ax.set_title(f"{frame}  {frame / motion.fps:.2f}s", fontsize=7, color="#333", pad=2)
    if title:
        fig.suptitle(title, fontsize=9)
    fig.tight_layout(pad=0.4, w_pad=1.2, h_pad=0.8)
    out = Path(path)
    fig.savefig(out, dpi=dpi, metadata={"Description": f"streamkey keyposes {frames.tolist()}"})
    plt.close(fig)
    return SheetResult(out, frames.tolist(), len(frames))


def driving_signals(motion: Motion, features: Features | None = None,
                    saliency: Keyframes | None = None) -> dict[str, np.ndarray]:
    """Per-frame driving signals (file numbering, NaN before `first_frame`).

    `speed`: Miura eq. 2-3, the 10 Hz low-passed body-frame positions of the 16 roles, step
    norm per second, in body heights / s. `saliency` (when a saliency result with its
    diagnostics is given): the weighted count of curves on which each frame is a saliency
    candidate, the cluster weight of Halit §3.1.4.
    """
    features = features or compute_features(motion)
    first = motion.first_frame
    n = motion.n_frames
    pos = features.role_positions(MIURA_ROLES)[first:].reshape(n - first, -1)
    pos = pos / features.body_height
    out = {"speed": np.full(n, np.nan)}
    if n - first >= 3:
        dt = motion.frame_time
        smooth = hp_filter(pos, hp_lambda(10.0, dt))
        step = np.linalg.norm(np.diff(smooth, axis=0), axis=1) / dt
        out["speed"][first + 1 :] = step
    info = saliency.info if saliency is not None else {}
    if "candidates" in info and "weights" in info:
        weight = np.zeros(n)
        for cand, w in zip(info["candidates"], np.asarray(info["weights"]), strict=False):
            weight[np.asarray(cand, dtype=np.int64)] += float(w)
        out["saliency"] = weight
    return out


def plot_signals(motion: Motion, results: dict[str, Keyframes],
                 path: str | os.PathLike[str], signals: dict[str, np.ndarray] | None = None,
                 dpi: int = 100) -> Path:
    """Write a PNG: the driving signals over time with one keyframe marker row per method."""
    plt = require_matplotlib()
    signals = signals if signals is not None else driving_signals(
        motion, saliency=results.get("saliency"))
    t = np.arange(motion.n_frames) / motion.fps
    names = [k for k in ("speed", "saliency") if k in signals]
    fig, axes = plt.subplots(len(names) + 1, 1, sharex=True, squeeze=False,
                             figsize=(10, 1.9 * len(names) + 0.4 * len(results) + 0.8),
                             gridspec_kw={"height_ratios": [3] * len(names)
                                          + [0.5 * max(len(results), 1)]})
    units = {"speed": "speed, 16 joints (heights/s)", "saliency": "saliency (candidate weight)"}
    for ax, name in zip(axes[:-1, 0], names, strict=True):
        ax.plot(t, signals[name], color="#333", lw=1)
        ax.set_ylabel(units[name], fontsize=8)
        for method, keys in results.items():
            for f in keys.frames:
                ax.axvline(f / motion.fps, color=METHOD_COLORS.get(method, "#9467bd"),
                           alpha=0.3, lw=0.8)
    lanes = axes[-1, 0]
    for i, (method, keys) in enumerate(results.items()):
        lanes.scatter(keys.frames / motion.fps, np.full(len(keys), i), marker="|", s=120,
                      color=METHOD_COLORS.get(method, "#9467bd"))
    lanes.set_yticks(range(len(results)), [f"{m} ({len(k)})" for m, k in results.items()],
                     fontsize=8)
    lanes.set_ylim(-0.7, len(results) - 0.3)
    lanes.set_xlabel("time (s)")
    axes[0, 0].set_title(f"{motion.name or 'motion'}: driving signals and keyframes",
                         fontsize=9)
    fig.tight_layout()
    out = Path(path)
    fig.savefig(out, dpi=dpi)
    plt.close(fig)
    return out
