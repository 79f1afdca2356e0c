"""Pictures of a clip's keyposes: the contact sheet and the driving-signal plot.

`contact_sheet` draws every keypose as a stick figure, in frame order, left to right in rows
(the thumbnail application of Halit & Capin, §4.5: a clip summarised by its salient poses),
`per_page` of them per PNG (`name-p1.png`, `name-p2.png`, ...), each captioned with its frame
and time under a title kept clear of the captions; without a path it returns the matplotlib
Figure (for notebooks and custom layouts).
Each pose is shown in its own body-aligned view (root translation and heading removed), so
the sheet compares postures, not where the actor stood. `plot_signals` draws the driving
signals of a clip (the body-frame speed of Miura eq. 2-3 and the saliency candidate weight
of Halit §3.1.4) with one marker row per method; curvefit's keys are per channel, not poses,
so they get their row but no pose markers over the signals.

matplotlib is an optional extra (`pip install 'streamkey[plot]'`); without it both functions
raise a `UsageError` saying so. The projections (`keypose_points`) need numpy only.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, overload

import numpy as np

from .errors import UsageError
from .features import Features, compute_features
from .keyframes import Keyframes
from .kinematics import forward_kinematics
from .motion import Motion
from .roles import MIURA_ROLES
from .signal import hp_filter, hp_lambda

if TYPE_CHECKING:
    from matplotlib.figure import Figure

__all__ = ["contact_sheet", "plot_signals", "keypose_points", "driving_signals", "SheetResult",
           "FIGURE_COLOR", "VIEWS", "require_matplotlib", "page_paths", "METHOD_COLORS"]

FIGURE_COLOR = "#1f4e8c"   # every stick figure of a sheet, nothing else, has this colour
VIEWS = {"front": 0.0, "three-quarter": 45.0, "side": 90.0}   # azimuth from the front, degrees
METHOD_COLORS = {"saliency": "#d62728", "speed": "#1f77b4", "simplify": "#2ca02c",
                 "uniform": "#7f7f7f", "decimate": "#ff7f0e", "optimal": "#bcbd22",
                 "isodata": "#8c564b", "curvefit": "#9467bd"}
OTHER_COLOR = "#17becf"
MISSING = "pictures need matplotlib: install streamkey[plot] (pip install 'streamkey[plot]')"


@dataclass
class SheetResult:
    """What a sheet holds: its (first) path, the frames drawn (file numbering), the figure
    count, and every page written."""

    path: Path
    frames: list[int]
    figures: int
    pages: list[Path] = field(default_factory=list)  # every file written (the first is path)


def require_matplotlib() -> Any:
    """Import matplotlib with the file-only Agg backend, or explain how to install it."""
    try:
        import matplotlib
    except ImportError:
        raise UsageError(MISSING) from None
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


def _new_figure(width: float, height: float) -> Figure:
    """A matplotlib Figure outside pyplot (no global state, the backend left alone; the
    caller keeps or saves it)."""
    try:
        import matplotlib  # noqa: F401  (the package itself: submodules may be cached)
        from matplotlib.figure import Figure
    except ImportError:
        raise UsageError(MISSING) from None

    return Figure(figsize=(width, height))


def page_paths(path: str | os.PathLike[str], pages: int) -> list[Path]:
    """`name.png` for one page, else `name-p1.png`, `name-p2.png`, ... beside it."""
    out = Path(path)
    if pages <= 1:
        return [out]
    return [out.with_name(f"{out.stem}-p{i}{out.suffix}") for i in range(1, pages + 1)]


@overload
def contact_sheet(motion: Motion, keys: Keyframes | list[int] | np.ndarray,
                  path: None = None, columns: int = 10,
                  view: str = "three-quarter", title: str | None = None,
                  cell_inches: float = 1.3, dpi: int = 100,
                  per_page: int | None = None) -> Figure: ...


@overload
def contact_sheet(motion: Motion, keys: Keyframes | list[int] | np.ndarray,
                  path: str | os.PathLike[str], columns: int = 10,
                  view: str = "three-quarter", title: str | None = None,
                  cell_inches: float = 1.3, dpi: int = 100,
                  per_page: int | None = None) -> SheetResult: ...


def contact_sheet(motion: Motion, keys: Keyframes | list[int] | np.ndarray,
                  path: str | os.PathLike[str] | None = None, columns: int = 10,
                  view: str = "three-quarter", title: str | None = None,
                  cell_inches: float = 1.3, dpi: int = 100,
                  per_page: int | None = None) -> SheetResult | Figure:
    """The keyposes as stick figures in frame order: PNG page(s) at `path` (a `SheetResult`;
    more than `per_page` keyposes go to `name-p1.png`, `name-p2.png`, ...), or without a
    path the matplotlib Figure of all of them."""
    frames = np.unique(np.asarray(keys.frames if isinstance(keys, Keyframes) else keys,
                                  dtype=np.int64))
    if len(frames) == 0:
        raise UsageError("contact sheet: no keyframes to draw")
    if columns < 1:
        raise UsageError("contact sheet: columns must be at least 1")
    if per_page is not None and per_page < 1:
        raise UsageError("contact sheet: per_page must be at least 1")
    pts = keypose_points(motion, frames, view)
    if path is None:
        return _sheet_figure(motion, frames, pts, columns, title, cell_inches)
    size = per_page or len(frames)
    starts = list(range(0, len(frames), size))
    paths = page_paths(path, len(starts))
    for page, (start, out) in enumerate(zip(starts, paths, strict=True), 1):
        part = slice(start, start + size)
        label = title
        if len(starts) > 1:
            label = f"{title}, page {page}/{len(starts)}" if title else f"page {page}/{len(starts)}"
        fig = _sheet_figure(motion, frames[part], pts[part], columns, label, cell_inches,
                            frames_like=min(size, len(frames)))
        fig.savefig(out, dpi=dpi,
                    metadata={"Description": f"streamkey keyposes {frames[part].tolist()}"})
    return SheetResult(paths[0], frames.tolist(), len(frames), paths)


def _sheet_figure(motion: Motion, frames: np.ndarray, pts: np.ndarray, columns: int,
                  title: str | None, cell_inches: float, frames_like: int | None = None) -> Figure:
    """One page: a grid of stick figures with a caption each and the title above them all.
    `frames_like`: the figure count the grid is sized for (every page of a sheet alike)."""
    from matplotlib.collections import LineCollection

    bones = np.array(_bones(motion))
    cols = min(columns, frames_like or len(frames))
    rows = -(-(frames_like or len(frames)) // cols)
    head = 0.4 if title else 0.0  # inches kept free for the title, above the top captions
    height = rows * cell_inches * 1.35 + head
    fig = _new_figure(cols * cell_inches, height)
    axes = fig.subplots(rows, cols, squeeze=False)
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
        ax.set_title(f"{frame} \u00b7 {frame / motion.fps:.2f} s", fontsize=8, color="#222",
                     pad=3)
    fig.tight_layout(pad=0.4, w_pad=1.0, h_pad=1.0, rect=(0, 0, 1, 1 - head / height))
    if title:
        fig.suptitle(title, fontsize=10, y=1 - 0.08 / height, va="top")
    return fig


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


@overload
def plot_signals(motion: Motion, results: dict[str, Keyframes], path: None = None,
                 signals: dict[str, np.ndarray] | None = None, dpi: int = 100) -> Figure: ...


@overload
def plot_signals(motion: Motion, results: dict[str, Keyframes], path: str | os.PathLike[str],
                 signals: dict[str, np.ndarray] | None = None, dpi: int = 100) -> Path: ...


def plot_signals(motion: Motion, results: dict[str, Keyframes],
                 path: str | os.PathLike[str] | None = None,
                 signals: dict[str, np.ndarray] | None = None, dpi: int = 100) -> Path | Figure:
    """The driving signals over time with one keyframe marker row per method: a PNG at `path`
    (its Path), or without a path the matplotlib Figure. Per-channel keys (curvefit: the
    union of every channel's keys, not poses) get their lane but no pose markers."""
    signals = signals if signals is not None else driving_signals(
        motion, saliency=results.get("saliency"))
    t = np.arange(motion.n_frames) / motion.fps
    names = [k for k in ("speed", "saliency") if k in signals]
    fig = _new_figure(10, 1.9 * len(names) + 0.4 * len(results) + 0.8)
    axes = fig.subplots(len(names) + 1, 1, sharex=True, squeeze=False,
                        gridspec_kw={"height_ratios": [3] * len(names)
                                     + [0.5 * max(len(results), 1)]})
    units = {"speed": "speed, 16 joints (heights/s)", "saliency": "saliency (candidate weight)"}
    poses = {m: k for m, k in results.items() if "per_channel" not in k.info}
    for ax, name in zip(axes[:-1, 0], names, strict=True):
        ax.plot(t, signals[name], color="#333", lw=1)
        ax.set_ylabel(units[name], fontsize=8)
        for method, keys in poses.items():
            for f in keys.frames:
                ax.axvline(f / motion.fps, color=METHOD_COLORS.get(method, OTHER_COLOR),
                           alpha=0.3, lw=0.8)
    lanes = axes[-1, 0]
    for i, (method, keys) in enumerate(results.items()):
        lanes.scatter(keys.frames / motion.fps, np.full(len(keys), i), marker="|",
                      s=120 if method in poses else 40,
                      color=METHOD_COLORS.get(method, OTHER_COLOR))
    lanes.set_yticks(range(len(results)),
                     [f"{m} ({len(k)}{'' if m in poses else ', per channel'})"
                      for m, k in results.items()], fontsize=8)
    lanes.set_ylim(-0.7, len(results) - 0.3)
    lanes.set_xlabel("time (s)")
    axes[0, 0].set_title(f"{motion.name or 'motion'}: driving signals and keyframes",
                         fontsize=9)
    fig.tight_layout()
    if path is None:
        return fig
    out = Path(path)
    fig.savefig(out, dpi=dpi)
    return out
