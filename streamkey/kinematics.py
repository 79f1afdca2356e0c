"""Forward kinematics, vectorised over frames (a Python loop over tree depth only)."""

from __future__ import annotations

import numpy as np

from .motion import POSITION_CHANNELS, ROTATION_CHANNELS, Motion, Skeleton

__all__ = ["euler_matrices", "local_rotations", "forward_kinematics", "FKResult", "body_height",
           "pelvis_frame", "point_names", "skeleton_defect", "MAX_DEPTH", "MIN_BODY_HEIGHT",
           "root_relative_joints"]

MAX_DEPTH = 256  # joints from the root to the deepest leaf; real skeletons stay under 40
MIN_BODY_HEIGHT = 1e-3  # file units; methods divide positions by the body height

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


def _depth_levels(parents: list[int]) -> list[np.ndarray]:
    depth = [0] * len(parents)
    for j, p in enumerate(parents):
        depth[j] = 0 if p < 0 else depth[p] + 1
    return [np.flatnonzero(np.array(depth) == d) for d in range(max(depth) + 1)]


class _RotationPlan:
    """Index patterns that turn a skeleton's Euler channels into matrices with few numpy ops."""

    def __init__(self, skeleton: Skeleton) -> None:
        assert skeleton.rotation_order is not None and skeleton.pre_rotations is not None
        j = skeleton.n_joints
        self.columns = np.zeros((j, 3), dtype=np.int64)
        self.mask = np.zeros((j, 3))
        axes = np.zeros((j, 3), dtype=np.int64)
        for joint, order in enumerate(skeleton.rotation_order):
            for k, name in enumerate(order):
                self.columns[joint, k] = skeleton.channel_start[joint] + skeleton.channels[
                    joint].index(name)
                self.mask[joint, k] = 1.0
                axes[joint, k] = _AXIS[name]
        eye = _axis_matrices(0, np.zeros(3)) * 0 + np.eye(3)
        ones, cos, sin = (np.zeros((3, 3, 3)) for _ in range(3))
        for a in range(3):
            i, k = [(1, 2), (2, 0), (0, 1)][a]
            ones[a] = eye[a]
            ones[a, i, i] = ones[a, k, k] = 0.0
            cos[a, i, i] = cos[a, k, k] = 1.0
            sin[a, i, k], sin[a, k, i] = -1.0, 1.0
        self.ones, self.cos, self.sin = ones[axes], cos[axes], sin[axes]
        pre = [p if p is not None else np.eye(3) for p in skeleton.pre_rotations]
        self.pre = np.array(pre) if any(p is not None for p in skeleton.pre_rotations) else None
        parents = np.array(skeleton.parents)
        self.levels = [(lv, parents[lv]) for lv in _depth_levels(skeleton.parents)[1:]]
        self.offsets = skeleton.offsets.copy()
        ends = sorted(skeleton.end_sites)
        self.n_points = j + len(ends)

        self.ends = np.array(ends, dtype=np.int64) if ends else None
        self.end_offsets = np.concatenate(
            [np.array([skeleton.end_sites[e] for e in ends]).reshape(-1, 3, 1),
             np.ones((len(ends), 1, 1))], axis=1)
        self.root_offset = skeleton.offsets[0]
        pos = [(a, skeleton.channel_index(0, c)) for a, c in enumerate(POSITION_CHANNELS)]
        self.root_axes = np.array([a for a, c in pos if c is not None], dtype=np.int64)
        self.root_columns = np.array([c for _, c in pos if c is not None], dtype=np.int64)

    def matrices(self, channels: np.ndarray) -> np.ndarray:
        """Local rotation matrices (n, J, 3, 3) of channel rows (n, C)."""
        rad = np.deg2rad(channels[:, self.columns]) * self.mask
        c = np.cos(rad)[..., None, None]
        s = np.sin(rad)[..., None, None]
        e = self.ones + c * self.cos + s * self.sin
        out = e[:, :, 0] @ e[:, :, 1] @ e[:, :, 2]
        if self.pre is not None:
            out = self.pre @ out @ self.pre.transpose(0, 2, 1)
        return out


_PLANS: dict[int, tuple[Skeleton, _RotationPlan]] = {}


def _plan(skeleton: Skeleton) -> _RotationPlan:
    cached = _PLANS.get(id(skeleton))
    if cached is None or cached[0] is not skeleton:
        cached = (skeleton, _RotationPlan(skeleton))
        _PLANS[id(skeleton)] = cached
    return cached[1]


def local_rotations(skeleton: Skeleton, channels: np.ndarray) -> np.ndarray:
    """Local rotation matrices (n_frames, n_joints, 3, 3) from channel values."""
    return _plan(skeleton).matrices(np.atleast_2d(np.asarray(channels, dtype=np.float64)))


def point_names(skeleton: Skeleton) -> list[str]:
    """Names of the FK points: every joint, then every end site as `<joint>_End`."""
    return skeleton.names + [f"{skeleton.names[j]}_End" for j in sorted(skeleton.end_sites)]


class FKResult:
    """World positions (n_frames, n_points, 3) of joints then end sites, and root rotations."""

    def __init__(self, positions: np.ndarray, root_rotation: np.ndarray, names: list[str]):
        self.positions = positions
        self.root_rotation = root_rotation
        self.names = names


def forward_kinematics(skeleton: Skeleton, channels: np.ndarray, chunk: int = 4096) -> FKResult:
    """World positions of every joint and end site for every frame (chunked to bound memory).

    Frames are independent and always go through the same arithmetic, so any split of a
    stream into blocks gives bit-identical results: offline and online features agree exactly.
    """
    channels = np.atleast_2d(np.asarray(channels, dtype=np.float64))
    plan = _plan(skeleton)
    n = channels.shape[0]
    positions = np.empty((n, plan.n_points, 3))
    root_rotation = np.empty((n, 3, 3))
    j = skeleton.n_joints
    for lo in range(0, n, chunk):
        block = channels[lo : lo + chunk]
        # Homogeneous transforms: one matmul per tree level moves rotation and position.
        world = np.zeros((len(block), j, 4, 4))
        world[..., :3, :3] = plan.matrices(block)
        world[..., :3, 3] = plan.offsets
        world[..., 3, 3] = 1.0
        world[:, 0, plan.root_axes, 3] += block[:, plan.root_columns]
        for level, par in plan.levels:
            world[:, level] = world[:, par] @ world[:, level]
        positions[lo : lo + chunk, :j] = world[..., :3, 3]
        if plan.ends is not None:
            positions[lo : lo + chunk, j:] = (world[:, plan.ends] @ plan.end_offsets)[..., :3, 0]
        root_rotation[lo : lo + chunk] = world[:, 0, :3, :3]
    return FKResult(positions, root_rotation, point_names(skeleton))


def pelvis_frame(fk: FKResult, pelvis: int = 0) -> np.ndarray:
    """Positions in the pelvis-fixed frame: R_pelvis^T (p - p_pelvis), (n, points, 3)."""
    rel = fk.positions - fk.positions[:, pelvis : pelvis + 1]
    return np.einsum("fba,fpb->fpa", fk.root_rotation, rel)


def root_relative_joints(positions: np.ndarray, n_joints: int) -> np.ndarray:
    """Joint positions (ROOT and JOINT, not End Sites) minus the root's, world orientation:
    the points of thesis eq. 4.1, (n, n_joints, 3)."""
    joints = positions[:, :n_joints]
    return joints - joints[:, :1]


def body_height(skeleton: Skeleton) -> float:
    """Height of the skeleton in its zero pose (offsets only): top minus bottom, file units."""
    zero = np.zeros((1, skeleton.n_channels))
    pts = forward_kinematics(skeleton, zero).positions[0]
    return float(pts[:, 1].max() - pts[:, 1].min())


def skeleton_defect(skeleton: Skeleton, limit: float = 1e6) -> str | None:
    """Why FK and the methods cannot use `skeleton` (too deep, huge or flat), or None."""
    depth = [0] * skeleton.n_joints
    for j, p in enumerate(skeleton.parents):
        depth[j] = 0 if p < 0 else depth[p] + 1
        if depth[j] > MAX_DEPTH:
            return f"expected a hierarchy at most {MAX_DEPTH} joints deep, got deeper"
    ends = list(skeleton.end_sites.values())
    vectors = np.concatenate([skeleton.offsets.reshape(-1, 3), np.reshape(ends, (-1, 3))])
    if not np.all(np.abs(vectors) <= limit):
        return f"expected OFFSET values within +-{limit:g}, got {np.abs(vectors).max():g}"
    height = body_height(skeleton)
    if not height >= MIN_BODY_HEIGHT:
        return (f"expected a skeleton with a body height (zero pose, Y extent) of at least"
                f" {MIN_BODY_HEIGHT:g}, got {height:g} (all OFFSETs zero or degenerate?)")
    return None


def motion_fk(motion: Motion) -> FKResult:
    """Forward kinematics of a whole motion."""
    return forward_kinematics(motion.skeleton, motion.channels)


assert set(_AXIS) == set(ROTATION_CHANNELS)
