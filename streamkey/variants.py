"""The same take as real sources deliver it: another rate, sensor noise, a calibration hold
before it, stillness after it, dropped frames.

A keypose is a property of the motion, so keys found on a variant, mapped back to the clean
take's frames (`Variant.to_clean`), should be the clean take's keys. Every variant is built
from the clean take's captured frames (a cgspeed reference frame is left out, and offered
only as the calibration pose). Rotations are resampled with quaternion slerp per joint, root
positions linearly; down-sampling by a whole factor takes every n-th frame.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from .errors import UsageError
from .evaluate import _nearest_euler, _rotation_groups, _slerp, _unwrapped, match_one_to_one
from .motion import Motion

__all__ = ["Variant", "clean_take", "resample", "with_noise", "with_calibration", "with_stillness",
           "with_drops", "standard_variants", "keys_in_take", "f1_against",
           "MATCH_TOLERANCE_S", "ROOT_UNITS_PER_DEGREE"]

MATCH_TOLERANCE_S = 4.0 / 120.0  # ±4 frames of 120 Hz: keys this close are the same key
ROOT_UNITS_PER_DEGREE = 0.17  # root-position noise per degree of rotation noise (CMU units)


@dataclass(frozen=True)
class Variant:
    """A variant of a clean take: `motion`, and where the take lies in it.

    Variant frame `f` is clean frame `(f - offset) * clean_fps / motion.fps`; frames in
    `[take_start, take_end)` are the take (outside: calibration hold, blend or stillness).
    """

    name: str
    motion: Motion
    clean_fps: float
    offset: int = 0
    take_start: int = 0
    take_end: int = -1

    def to_clean(self, frames: Sequence[int] | np.ndarray) -> np.ndarray:
        """Variant frame numbers as (fractional) clean-take frame numbers."""
        f = np.asarray(frames, dtype=np.float64)
        return (f - self.offset) * self.clean_fps / self.motion.fps

    def in_take(self, frames: Sequence[int] | np.ndarray) -> np.ndarray:
        """The frames that lie inside the take."""
        f = np.asarray(frames, dtype=np.int64)
        end = self.motion.n_frames if self.take_end < 0 else self.take_end
        return f[(f >= self.take_start) & (f < end)]


def _clean(motion: Motion) -> Motion:
    """The captured frames with rotations unwrapped, numbered from 0."""
    return Motion(motion.skeleton, _unwrapped(motion), motion.fps, 0, motion.name)


def _interpolate(x: np.ndarray, motion: Motion, at: np.ndarray) -> np.ndarray:
    """Channels at fractional frame positions `at`: slerp for rotations, lerp otherwise."""
    a = np.clip(np.floor(at).astype(np.int64), 0, len(x) - 1)
    b = np.minimum(a + 1, len(x) - 1)
    t = at - a
    out: np.ndarray = x[a] + t[:, None] * (x[b] - x[a])
    for seq, cols in _rotation_groups(motion.skeleton).items():
        q0 = Rotation.from_euler(seq, x[a][:, cols].reshape(-1, 3), degrees=True).as_quat()
        q1 = Rotation.from_euler(seq, x[b][:, cols].reshape(-1, 3), degrees=True).as_quat()
        nj = len(cols)
        q = _slerp(q0.reshape(-1, nj, 4), q1.reshape(-1, nj, 4), t[:, None, None])
        euler = Rotation.from_quat(q.reshape(-1, 4)).as_euler(seq, degrees=True)
        ref = out[:, cols].reshape(-1, 3)
        out[:, cols.reshape(-1)] = _nearest_euler(euler, ref).reshape(len(at), nj * 3)
    return out


def clean_take(motion: Motion) -> Variant:
    """The clean take itself (captured frames, numbered from 0): what variants compare with."""
    return Variant("clean", _clean(motion), motion.fps)


def resample(motion: Motion, fps: float) -> Variant:
    """The take at `fps`: every n-th frame for a whole down-sampling factor, else slerp."""
    clean = _clean(motion)
    step = clean.fps / fps
    if step >= 1 and abs(step - round(step)) < 1e-9:
        x = clean.channels[:: int(round(step))]
    else:
        n = int(np.floor((clean.n_frames - 1) / step)) + 1
        x = _interpolate(clean.channels, clean, np.arange(n) * step)
    out = Motion(motion.skeleton, x, fps, 0, f"{motion.name}@{fps:g}Hz")
    return Variant(f"{fps:g} Hz", out, clean.fps)


def with_noise(motion: Motion, degrees: float, seed: int = 0,
               root_units: float | None = None) -> Variant:
    """Gaussian sensor noise: `degrees` on every rotation channel, `root_units` (default
    `degrees` x 0.17) on the root position channels."""
    clean = _clean(motion)
    rng = np.random.default_rng(seed)
    x = clean.channels.copy()
    rot = motion.skeleton.rotation_columns()
    pos = motion.skeleton.position_columns()
    x[:, rot] += rng.normal(0.0, degrees, (len(x), len(rot)))
    sigma_root = degrees * ROOT_UNITS_PER_DEGREE if root_units is None else root_units
    x[:, pos] += rng.normal(0.0, sigma_root, (len(x), len(pos)))
    return Variant(f"noise {degrees:g}°", Motion(motion.skeleton, x, clean.fps, 0,
                                                 f"{motion.name}+noise"), clean.fps)


def _calibration_pose(motion: Motion, first: np.ndarray) -> np.ndarray:
    """The file's own reference T-pose if it has one, else every rotation zero; the root
    stands where the take starts."""
    pose = motion.channels[0].copy() if motion.first_frame > 0 else np.zeros_like(first)
    rot = motion.skeleton.rotation_columns()
    if motion.first_frame == 0:
        pose[rot] = 0.0
    pos = motion.skeleton.position_columns()
    pose[pos] = first[pos]
    return pose


def with_calibration(motion: Motion, hold_s: float = 2.0, blend_s: float = 0.5) -> Variant:
    """A calibration hold (the reference T-pose) for `hold_s`, a `blend_s` slerp into the
    take's first frame, then the take."""
    clean = _clean(motion)
    hold = int(round(hold_s * clean.fps))
    blend = int(round(blend_s * clean.fps))
    pose = _calibration_pose(motion, clean.channels[0])
    pair = np.stack([pose, clean.channels[0]])
    ramp = _interpolate(pair, clean, np.arange(1, blend + 1) / (blend + 1))
    x = np.concatenate([np.repeat(pose[None], hold, axis=0), ramp, clean.channels])
    offset = hold + blend
    out = Motion(motion.skeleton, x, clean.fps, 0, f"{motion.name}+calibration")
    return Variant("calibration before", out, clean.fps, offset, offset)


def with_stillness(motion: Motion, seconds: float = 3.0) -> Variant:
    """The take, then its last frame held for `seconds`."""
    clean = _clean(motion)
    hold = int(round(seconds * clean.fps))
    x = np.concatenate([clean.channels, np.repeat(clean.channels[-1:], hold, axis=0)])
    out = Motion(motion.skeleton, x, clean.fps, 0, f"{motion.name}+still")
    return Variant("stillness after", out, clean.fps, 0, 0, clean.n_frames)


def with_drops(motion: Motion, fraction: float, seed: int = 0) -> tuple[Variant, np.ndarray]:
    """The take with `fraction` of its inner frames lost, as a receiver that bridges holes
    linearly sees it, and the lost frame numbers (for a stream that skips those seqs)."""
    if not 0.0 <= fraction < 0.5:
        raise UsageError(f"drop fraction must be in [0, 0.5), got {fraction}")
    clean = _clean(motion)
    rng = np.random.default_rng(seed)
    n = clean.n_frames
    lost = np.sort(rng.choice(np.arange(1, n - 1), int(round(fraction * n)), replace=False))
    kept = np.setdiff1d(np.arange(n), lost)
    x = clean.channels.copy()
    for c in range(x.shape[1]):
        x[lost, c] = np.interp(lost, kept, clean.channels[kept, c])
    out = Motion(motion.skeleton, x, clean.fps, 0, f"{motion.name}-drops")
    return Variant(f"{fraction:.0%} dropped", out, clean.fps), lost


def standard_variants(motion: Motion) -> list[Variant]:
    """The variants every method must be invariant to: 30 and 60 Hz, 0.3° noise,
    a calibration hold before, stillness after, 1 % dropped frames."""
    return [resample(motion, 60.0), resample(motion, 30.0), with_noise(motion, 0.3),
            with_calibration(motion), with_stillness(motion), with_drops(motion, 0.01)[0]]


def keys_in_take(variant: Variant, frames: Sequence[int] | np.ndarray) -> np.ndarray:
    """Keys of `variant` inside its take, as clean-take frame numbers."""
    return variant.to_clean(variant.in_take(frames))


def f1_against(clean_keys: Sequence[int] | np.ndarray, variant_keys_clean: np.ndarray,
               clean_fps: float) -> float:
    """F1 of one-to-one matching within ±4 frames of 120 Hz (in the clean take's frames)."""
    return match_one_to_one(variant_keys_clean, clean_keys, MATCH_TOLERANCE_S * clean_fps)[3]
