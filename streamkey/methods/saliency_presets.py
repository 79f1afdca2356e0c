"""Parameters of multiscale motion saliency: the presets, their check, and the "auto" rule
(a high percentile of the body speed over the first seconds of motion), shared by the
offline `extract`, the online `Online` and `AutoOnline` (`streamkey.methods.saliency` states
the method).
"""

from __future__ import annotations

import numpy as np

from ..errors import UsageError
from ..features import Features
from ..roles import MIURA_ROLES
from ..units import Duration, DurationLike
from .saliency_math import REFERENCE_FPS, frames_at

__all__ = ["METHOD", "PRESETS", "UPDATE_EVERY", "AUTO_SPEED_THRESHOLD", "AUTO_SECONDS",
           "AUTO_QUANTILE",
           "STILL_SPEED", "HISTORY_SECONDS", "auto_frames", "step_speeds", "moving",
           "auto_preset", "choose_preset", "preset_sigma", "resolve_params"]

METHOD = "saliency"
# sigma in frames of 120 Hz (`REFERENCE_FPS`): 1/12 s and 1/40 s of motion at any rate
PRESETS: dict[str, tuple[float, int]] = {"low": (10.0, 7), "high": (3.0, 10)}
UPDATE_EVERY = Duration.seconds(10.0)  # online: the basis is recomputed at least this often
AUTO_SPEED_THRESHOLD = 1.03  # body heights per second, the 90th percentile of the steps
AUTO_QUANTILE = 90.0  # percent: "auto" looks at the fast steps, not at the slow ones
AUTO_SECONDS = 1.0  # "auto" decides on the first 1 s of motion (offline and online alike)
STILL_SPEED = 0.005  # body heights per second: slower steps are not motion for "auto"
HISTORY_SECONDS = 10.0  # online: past kept for recomputation when the basis changes



# --------------------------------------------------------------------------- parameters

def auto_frames(fps: float) -> int:
    """Frames the "auto" rule looks at: the first `AUTO_SECONDS` from the first moving step
    (`moving`) on."""
    return max(2, int(round(AUTO_SECONDS * float(fps))))


def step_speeds(p: np.ndarray) -> np.ndarray:
    """Per frame step and body part, the distance moved (body heights) between consecutive
    rows of Miura-role positions `p` (n, parts, 3): (n - 1, parts)."""
    steps: np.ndarray = np.linalg.norm(np.diff(p, axis=0), axis=2)
    return steps


def moving(steps: np.ndarray, fps: float) -> np.ndarray:
    """Which steps of `step_speeds` move: mean part speed above `STILL_SPEED` (a calibration
    hold or a frozen source does not; captured motion, even standing, does)."""
    moves: np.ndarray = steps.mean(axis=1) * fps > STILL_SPEED
    return moves


def auto_preset(steps: np.ndarray, fps: float) -> tuple[str, float]:
    """The "auto" rule on the moving steps of its window (rows of `step_speeds`):
    ("high" | "low", the `AUTO_QUANTILE` percentile of the steps' mean part speed, body
    heights/s). A high percentile, not the mean: slow steps that are not the take's own (a
    blend out of a calibration pose, a stop into stillness after a short take) leave it."""
    if len(steps) == 0:
        return "low", 0.0
    speed = float(np.percentile(steps.mean(axis=1), AUTO_QUANTILE) * fps)
    return ("high" if speed >= AUTO_SPEED_THRESHOLD else "low"), speed


def choose_preset(features: Features, first: int) -> tuple[str, float]:
    """The "auto" rule: ("high" | "low", body speed in body heights per second) over the
    moving steps of the first `AUTO_SECONDS` from the first moving step on (a calibration
    hold or stillness counts for nothing), as the online keyframer decides it (causal)."""
    fps = features.motion.fps
    p = features.role_positions(MIURA_ROLES)[first:] / features.body_height
    steps = step_speeds(p)
    mv = moving(steps, fps)
    if not mv.any():
        return auto_preset(steps[:0], fps)
    start = int(np.argmax(mv))
    window = mv[start : start + auto_frames(fps) - 1]
    return auto_preset(steps[np.flatnonzero(window) + start], fps)


def preset_sigma(preset: str) -> Duration:
    """The base scale of a preset ("low" or "high") in seconds."""
    return Duration.seconds(PRESETS[preset][0] / REFERENCE_FPS)


def resolve_params(sigma: DurationLike | None, k: int | None, preset: str, contact: bool,
                   fps: float = REFERENCE_FPS) -> tuple[float, int]:
    """Check parameters and fill sigma / k from a resolved preset ("low" or "high"): sigma
    in frames at `fps` (a plain number is already frames; the presets' are in seconds, at
    least half a frame), and k."""
    if preset not in PRESETS:
        raise UsageError(f"saliency: preset must be 'auto', 'low' or 'high', got {preset!r}")
    k0 = PRESETS[preset][1]
    if sigma is None:
        sigma = max(0.5, frames_at(preset_sigma(preset), fps))
    else:
        given = sigma
        try:
            sigma = frames_at(sigma, fps)
        except (TypeError, ValueError):
            raise UsageError(f"saliency: sigma must be a number of frames or a Duration, "
                             f"got {given!r}") from None
        if not (np.isfinite(sigma) and sigma >= 0.5):
            raise UsageError(f"saliency: sigma must be >= 0.5 frames, got {given} "
                             f"({sigma:g} frames at {fps:g} Hz)")
    k = k0 if k is None else k
    if isinstance(k, bool) or not isinstance(k, (int, np.integer)) or k < 1:
        raise UsageError(f"saliency: k must be a positive integer, got {k!r}")
    if contact and k < 3:
        raise UsageError("saliency: contact handling replaces two curves; it needs k >= 3")
    return sigma, int(k)
