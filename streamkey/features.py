"""Derived signals of a motion, computed once and shared by every method (DESIGN §2).

Offline: `compute_features(motion)`. Every array is indexed by the motion's own frame numbers
(reference frame included); methods slice from `motion.first_frame`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .kinematics import FKResult, body_height, forward_kinematics, pelvis_frame
from .motion import Motion
from .roles import resolve_roles
from .signal import unwrap_degrees

__all__ = ["Features", "compute_features"]


@dataclass
class Features:
    """FK positions, pelvis-frame positions, foot heights, unwrapped rotations, body height."""

    motion: Motion
    fk: FKResult
    pelvis_positions: np.ndarray
    roles: dict[str, int]
    body_height: float
    rotations: np.ndarray

    @property
    def foot_heights(self) -> np.ndarray:
        """World vertical (Y) position of the left and right ankle, (n_frames, 2)."""
        p = self.fk.positions
        return np.stack([p[:, self.roles["left_ankle"], 1], p[:, self.roles["right_ankle"], 1]],
                        axis=1)

    def role_positions(self, roles: tuple[str, ...], pelvis: bool = True) -> np.ndarray:
        """Positions of the joints playing `roles`, (n_frames, len(roles), 3)."""
        src = self.pelvis_positions if pelvis else self.fk.positions
        return src[:, [self.roles[r] for r in roles]]


def compute_features(motion: Motion, role_mapping: dict[str, str] | None = None) -> Features:
    """Compute FK and derived signals for every frame of `motion`."""
    skel = motion.skeleton
    fk = forward_kinematics(skel, motion.channels)
    roles = resolve_roles(skel, role_mapping)
    rot_cols = skel.rotation_columns()
    rotations = unwrap_degrees(motion.channels[:, rot_cols])
    return Features(motion, fk, pelvis_frame(fk, roles["pelvis"]), roles, body_height(skel),
                    rotations)
