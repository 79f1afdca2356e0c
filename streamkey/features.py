"""Derived signals of a motion, computed once and shared by every method.

Offline: `compute_features(motion)`. Every array is indexed by the motion's own frame numbers
(reference frame included); methods slice from `motion.first_frame`. The captured frames go
through the sensor-noise front end first (`filters.FrontEnd`: rotations unwrapped, rotations
and root position low-passed at `noise_cutoff_hz`, the same numbers an online stream of the
clip gets), and `Features.motion` is that filtered motion: a method reads its channels, never
the raw ones. The unwrapped rotations are computed up front, FK on first use (compiled
kernels writing straight into the results); the pelvis frame on demand, for the points a
method asks for (`role_positions`, `pelvis_points`).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from .filters import DEFAULT_NOISE_CUTOFF_HZ, FrontEnd
from .kinematics import FKResult, body_height, forward_kinematics, pelvis_frame
from .motion import Motion, without_lead
from .roles import resolve_roles
from .signal import unwrap_columns

__all__ = ["Features", "compute_features", "filtered_motion", "DEFAULT_NOISE_CUTOFF_HZ"]


class Features:
    """FK positions, pelvis-frame positions, foot heights, unwrapped rotations, body height,
    of `motion` (the filtered motion when the noise filter is on)."""

    def __init__(self, motion: Motion, fk: FKResult | None, roles: dict[str, int],
                 body_height: float, rotations: np.ndarray,
                 noise_cutoff_hz: float | None = None) -> None:
        self.motion = motion
        self._fk = fk
        self.roles = roles
        self.body_height = body_height
        self.rotations = rotations
        self.noise_cutoff_hz = noise_cutoff_hz
        self._pelvis: np.ndarray | None = None

    @property
    def fk(self) -> FKResult:
        """World FK of every joint of `motion` (computed on first use)."""
        if self._fk is None:
            self._fk = forward_kinematics(self.motion.skeleton, self.motion.channels)
        return self._fk

    @property
    def pelvis_positions(self) -> np.ndarray:
        """Every FK point in the pelvis-fixed frame, (n_frames, n_points, 3) (on first use)."""
        if self._pelvis is None:
            self._pelvis = pelvis_frame(self.fk, self.roles["pelvis"])
        return self._pelvis

    def pelvis_points(self, points: Sequence[int]) -> np.ndarray:
        """Some FK points in the pelvis-fixed frame (the bits of `pelvis_positions`)."""
        idx = np.asarray(points, dtype=np.int64).reshape(-1)
        if self._pelvis is not None:
            return self._pelvis[:, idx]
        return pelvis_frame(self.fk, self.roles["pelvis"], idx)

    @property
    def foot_heights(self) -> np.ndarray:
        """World vertical (Y) position of the left and right ankle, (n_frames, 2)."""
        p = self.fk.positions
        return np.stack([p[:, self.roles["left_ankle"], 1], p[:, self.roles["right_ankle"], 1]],
                        axis=1)

    def role_positions(self, roles: tuple[str, ...], pelvis: bool = True) -> np.ndarray:
        """Positions of the joints playing `roles`, (n_frames, len(roles), 3)."""
        idx = [self.roles[r] for r in roles]
        return self.pelvis_points(idx) if pelvis else self.fk.positions[:, idx]


def filtered_motion(motion: Motion, noise_cutoff_hz: float | None = DEFAULT_NOISE_CUTOFF_HZ
                    ) -> tuple[Motion, np.ndarray]:
    """`motion` through the front end, and its unwrapped rotation columns. The captured
    frames are one window, unwrapped from the first captured frame as a stream of them is
    (filter on or off); a reference frame before them stays as it is, and so do lead frames
    at `first_frame` (`motion.without_lead`: `first_frame` moves past them, as a stream drops
    them). Off (None or 0): `motion` itself, or it past its lead frames."""
    motion = without_lead(motion)
    skel = motion.skeleton
    cols = skel.rotation_columns()
    front = FrontEnd(skel, motion.fps, noise_cutoff_hz)
    first = motion.first_frame
    rotations = np.empty((motion.n_frames, len(cols)))
    rotations[:first] = unwrap_columns(motion.channels[:first], cols)
    if front.lowpass is None:
        rotations[first:] = unwrap_columns(motion.channels[first:], cols)
        return motion, rotations
    rows = front.run(motion.channels[first:])
    channels = motion.channels.copy()
    channels[first:] = rows.channels
    rotations[first:] = rows.rotations
    return Motion(skel, channels, motion.fps, first, motion.name), rotations


def compute_features(motion: Motion, role_mapping: dict[str, str] | None = None,
                     noise_cutoff_hz: float | None = DEFAULT_NOISE_CUTOFF_HZ) -> Features:
    """Derived signals for every frame of `motion`, after the sensor-noise filter
    (`noise_cutoff_hz` in Hz; None or 0: off)."""
    skel = motion.skeleton
    filtered, rotations = filtered_motion(motion, noise_cutoff_hz)
    roles = resolve_roles(skel, role_mapping)
    cutoff = noise_cutoff_hz if filtered.channels is not motion.channels else None  # filtered
    return Features(filtered, None, roles, body_height(skel), rotations, cutoff)
