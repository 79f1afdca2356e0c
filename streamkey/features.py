"""Derived signals of a motion, computed once and shared by every method (DESIGN §2).

Offline: `compute_features(motion)`. Every array is indexed by the motion's own frame numbers
(reference frame included); methods slice from `motion.first_frame`. FK and the unwrapped
rotations are computed up front (compiled kernels writing straight into the results); the
pelvis frame on demand, for the points a method asks for (`role_positions`, `pelvis_points`).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from .kinematics import FKResult, body_height, forward_kinematics, pelvis_frame
from .motion import Motion
from .roles import resolve_roles
from .signal import unwrap_columns

__all__ = ["Features", "compute_features"]


class Features:
    """FK positions, pelvis-frame positions, foot heights, unwrapped rotations, body height."""

    def __init__(self, motion: Motion, fk: FKResult, roles: dict[str, int], body_height: float,
                 rotations: np.ndarray) -> None:
        self.motion = motion
        self.fk = fk
        self.roles = roles
        self.body_height = body_height
        self.rotations = rotations
        self._pelvis: np.ndarray | None = None

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


def compute_features(motion: Motion, role_mapping: dict[str, str] | None = None) -> Features:
    """Compute FK and derived signals for every frame of `motion`."""
    skel = motion.skeleton
    fk = forward_kinematics(skel, motion.channels)
    roles = resolve_roles(skel, role_mapping)
    rotations = unwrap_columns(motion.channels, skel.rotation_columns())
    return Features(motion, fk, roles, body_height(skel), rotations)
