"""Forward kinematics, vectorised over frames (a Python loop over tree depth only)."""

from __future__ import annotations

import numpy as np

from .motion import ROTATION_CHANNELS, Motion, Skeleton

__all__ = ["euler_matrices", "local_rotations", "forward_kinematics", "FKResult", "body_height",
           "pelvis_frame", "point_names"]

_AXIS = {"Xrotation": 0, "Yrotation": 1, "Zrotation": 2}


def _axis_matrices(axis: int, radians: np.ndarray) -> np.ndarray:
    c, s = np.cos(radians), np.sin(radians)
    out = np.zeros(radians.shape + (3, 3))
    i, j = [(1, 2), (2, 0), (0, 1)][axis]
    out[..., axis, axis] = 1.0
    out[..., i, i] = c
    out[..., j, j] = c
    out[..., i, j] = -s
    out[..., j, i] = s
    return out


def euler_matrices(degrees: np.ndarray, order: list[str]) -> np.ndarray:
    """Rotation matrices of intrinsic Euler angles (..., len(order)) applied left to right."""
    out = None
    radians = np.deg2rad(degrees)
    for k, name in enumerate(order):
        m = _axis_matrices(_AXIS[name], radians[..., k])
        out = m if out is None else out @ m
    if out is None:
        out = np.broadcast_to(np.eye(3), degrees.shape[:-1] + (3, 3)).copy()
    return out


def local_rotations(skeleton: Skeleton, channels: np.ndarray) -> np.ndarray:
    """Local rotation matrices (n_frames, n_joints, 3, 3) from channel values."""
    n = channels.shape[0]
    out = np.empty((n, skeleton.n_joints, 3, 3))
    assert skeleton.rotation_order is not None and skeleton.pre_rotations is not None
    groups: dict[tuple[str, ...], list[int]] = {}
    for j, order in enumerate(skeleton.rotation_order):
        groups.setdefault(tuple(order), []).append(j)
    for order, joints in groups.items():
        cols = [[skeleton.channel_start[j] + skeleton.channels[j].index(c) for c in order]
                for j in joints]
        angles = channels[:, np.array(cols, dtype=int)] if order else np.zeros((n, len(joints), 0))
        out[:, joints] = euler_matrices(angles, list(order))
    for j, pre in enumerate(skeleton.pre_rotations):
        if pre is not None:
            out[:, j] = pre @ out[:, j] @ pre.T
    return out


def _depth_levels(parents: list[int]) -> list[np.ndarray]:
    depth = [0] * len(parents)
    for j, p in enumerate(parents):
        depth[j] = 0 if p < 0 else depth[p] + 1
    return [np.flatnonzero(np.array(depth) == d) for d in range(max(depth) + 1)]


def point_names(skeleton: Skeleton) -> list[str]:
    """Names of the FK points: every joint, then every end site as `<joint>_End`."""
    return skeleton.names + [f"{skeleton.names[j]}_End" for j in sorted(skeleton.end_sites)]


class FKResult:
    """World positions (n_frames, n_points, 3) of joints then end sites, and root rotations."""

    def __init__(self, positions: np.ndarray, root_rotation: np.ndarray, names: list[str]):
        self.positions = positions
        self.root_rotation = root_rotation
        self.names = names


def forward_kinematics(skeleton: Skeleton, channels: np.ndarray,
                       chunk: int = 8192) -> FKResult:
    """World positions of every joint and end site for every frame (chunked to bound memory)."""
    channels = np.atleast_2d(np.asarray(channels, dtype=np.float64))
    n = channels.shape[0]
    ends = sorted(skeleton.end_sites)
    positions = np.empty((n, skeleton.n_joints + len(ends), 3))
    root_rotation = np.empty((n, 3, 3))
    levels = _depth_levels(skeleton.parents)
    parents = np.array(skeleton.parents)
    pos_cols = [skeleton.channel_index(0, c) for c in ("Xposition", "Yposition", "Zposition")]
    end_offsets = np.array([skeleton.end_sites[j] for j in ends]).reshape(-1, 3)
    for lo in range(0, n, chunk):
        block = channels[lo : lo + chunk]
        local = local_rotations(skeleton, block)
        world = np.empty_like(local)
        pos = positions[lo : lo + chunk]
        root = skeleton.offsets[0] + np.zeros((len(block), 3))
        for axis, col in enumerate(pos_cols):
            if col is not None:
                root[:, axis] += block[:, col]
        world[:, 0] = local[:, 0]
        pos[:, 0] = root
        for level in levels[1:]:
            par = parents[level]
            world[:, level] = world[:, par] @ local[:, level]
            pos[:, level] = pos[:, par] + np.einsum("fjab,jb->fja", world[:, par],
                                                    skeleton.offsets[level])
        if ends:
            pos[:, skeleton.n_joints :] = pos[:, ends] + np.einsum(
                "fjab,jb->fja", world[:, ends], end_offsets)
        root_rotation[lo : lo + chunk] = world[:, 0]
    return FKResult(positions, root_rotation, point_names(skeleton))


def pelvis_frame(fk: FKResult, pelvis: int = 0) -> np.ndarray:
    """Positions in the pelvis-fixed frame: R_pelvis^T (p - p_pelvis), (n, points, 3)."""
    rel = fk.positions - fk.positions[:, pelvis : pelvis + 1]
    return np.einsum("fba,fpb->fpa", fk.root_rotation, rel)


def body_height(skeleton: Skeleton) -> float:
    """Height of the skeleton in its zero pose (offsets only): top minus bottom point, file units."""
    zero = np.zeros((1, skeleton.n_channels))
    pts = forward_kinematics(skeleton, zero).positions[0]
    return float(pts[:, 1].max() - pts[:, 1].min())


def motion_fk(motion: Motion) -> FKResult:
    """Forward kinematics of a whole motion."""
    return forward_kinematics(motion.skeleton, motion.channels)


assert set(_AXIS) == set(ROTATION_CHANNELS)
