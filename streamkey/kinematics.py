"""Forward kinematics, vectorised over frames (a Python loop over tree depth only)."""

from __future__ import annotations

import numpy as np

from .motion import POSITION_CHANNELS, ROTATION_CHANNELS, Motion, Skeleton

__all__ = ["euler_matrices", "local_rotations", "forward_kinematics", "FKResult", "body_height",
           "pelvis_frame", "point_names", "skeleton_defect", "MAX_DEPTH", "MIN_BODY_HEIGHT",
           "root_relative_joints", "to_pelvis", "joint_heights"]

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

    def __init__(self, skeleton: Skeleton, joints: tuple[int, ...] | None = None) -> None:
        assert skeleton.rotation_order is not None and skeleton.pre_rotations is not None
        j = skeleton.n_joints
        parents = np.array(skeleton.parents)
        keep = np.ones(j, dtype=bool)
        if joints is not None:  # a sub-plan: those joints and their ancestors only
            keep[:] = False
            for q in joints:
                while q >= 0 and not keep[q]:
                    keep[q] = True
                    q = int(parents[q])
        # World transforms are held in tree-level order (each level one contiguous slice, its
        # joints sorted by parent), so a level is one gather of parents and one matmul in place.
        levels = [lv[keep[lv]] for lv in _depth_levels(skeleton.parents)]
        levels = [lv[np.argsort(parents[lv], kind="stable")] for lv in levels if len(lv)]
        order = np.concatenate(levels)
        self.order = order
        self.where = np.full(j, -1, dtype=np.int64)  # joint -> row in level order
        self.where[order] = np.arange(len(order))
        self.levels = []
        lo = self.n_roots = len(levels[0])
        for lv in levels[1:]:
            self.levels.append((lo, lo + len(lv), self.where[parents[lv]]))
            lo += len(lv)
        k = len(order)
        columns = np.zeros((k, 3), dtype=np.int64)
        # Each elementary axis matrix entry is 0, 1, cos, sin or -sin of one angle: one gather
        # from [0, 1, cos..., sin..., -sin...] builds all of them (an unused slot: identity).
        gather = np.zeros((k, 3, 3, 3), dtype=np.int64)
        gather[:] = np.eye(3, dtype=np.int64)
        for row, joint in enumerate(order):
            for slot_k, name in enumerate(skeleton.rotation_order[joint]):
                columns[row, slot_k] = skeleton.channel_start[joint] + skeleton.channels[
                    joint].index(name)
                a = _AXIS[name]
                i, m = [(1, 2), (2, 0), (0, 1)][a]
                slot = row * 3 + slot_k
                g = np.zeros((3, 3), dtype=np.int64)
                g[a, a] = 1
                g[i, i] = g[m, m] = 2 + slot
                g[m, i] = 2 + 3 * k + slot
                g[i, m] = 2 + 6 * k + slot
                gather[row, slot_k] = g
        self.columns_flat = columns.reshape(-1)
        self.gather_levels = gather.reshape(-1)
        pre = [p if p is not None else np.eye(3) for p in skeleton.pre_rotations]
        self.pre = np.array(pre) if any(p is not None for p in skeleton.pre_rotations) else None
        self.pre_levels = None if self.pre is None else self.pre[order]
        if joints is None:  # natural joint order, for `local_rotations`
            self.gather = gather.reshape(k, -1)[self.where].reshape(-1)
        self.skeleton = skeleton
        self.parents = list(skeleton.parents)
        self.offsets = skeleton.offsets.copy()
        ends = sorted(skeleton.end_sites)
        self.n_points = j + len(ends)
        self.names = point_names(skeleton)
        self.ends = np.array(ends, dtype=np.int64) if ends else None
        self.end_offsets = np.concatenate(
            [np.array([skeleton.end_sites[e] for e in ends]).reshape(-1, 3, 1),
             np.ones((len(ends), 1, 1))], axis=1)
        self.root_offset = skeleton.offsets[0]
        pos = [(a, skeleton.channel_index(0, c)) for a, c in enumerate(POSITION_CHANNELS)]
        self.root_axes = np.array([a for a, c in pos if c is not None], dtype=np.int64)
        self.root_columns = np.array([c for _, c in pos if c is not None], dtype=np.int64)
        c0 = int(self.root_columns[0]) if len(self.root_columns) else 0
        if list(self.root_axes) == [0, 1, 2] and list(self.root_columns) == [c0, c0 + 1, c0 + 2]:
            self.root_axes, self.root_columns = slice(0, 3), slice(c0, c0 + 3)  # type: ignore
        self.template = np.zeros((k, 4, 4))
        self.template[:, :3, 3] = self.offsets[order]
        self.template[:, 3, 3] = 1.0
        self._subplans: dict[tuple[int, ...], _RotationPlan] = {}
        # One-frame path (`world_one`): the same ufuncs and products on 1-D / (J, 4, 4) arrays.
        # A level whose parents are consecutive rows reads them as a view, not a gather.
        self.levels_one = [(lo, hi, _as_slice(par)) for lo, hi, par in self.levels]
        self.root_template = self.template[0, self.root_axes, 3].copy()
        # flat indices of each joint's translation in a (J, 4, 4) world, in joint order
        self.translations = (self.where[:, None] * 16 + [3, 7, 11]).ravel()

    def subplan(self, joints: tuple[int, ...]) -> _RotationPlan:
        """The plan for some joints and their ancestors (cached)."""
        got = self._subplans.get(joints)
        if got is None:
            got = self._subplans[joints] = _RotationPlan(self.skeleton, joints)
        return got

    def matrices(self, channels: np.ndarray, level_order: bool = False) -> np.ndarray:
        """Local rotation matrices (n, J, 3, 3) of channel rows (n, C)."""
        n, j = channels.shape[0], len(self.order)
        rad = np.deg2rad(channels[:, self.columns_flat])
        s = np.sin(rad)
        vals = np.concatenate([np.zeros((n, 1)), np.ones((n, 1)), np.cos(rad), s, -s], axis=1)
        gather, pre = (self.gather_levels, self.pre_levels) if level_order else (
            self.gather, self.pre)
        e = vals[:, gather].reshape(n, j, 3, 3, 3)
        out = e[:, :, 0] @ e[:, :, 1] @ e[:, :, 2]
        if pre is not None:
            out = pre @ out @ pre.transpose(0, 2, 1)
        return out

    def world_one(self, row: np.ndarray) -> np.ndarray:
        """`world` of one channel row (C,) as (J, 4, 4): bit for bit the same products, with
        a third of the numpy calls (one frame per push is the online case)."""
        k3 = len(self.columns_flat)
        rad = np.deg2rad(row[self.columns_flat])
        vals = np.empty(2 + 3 * k3)
        vals[0], vals[1] = 0.0, 1.0
        np.cos(rad, out=vals[2 : 2 + k3])
        sin = np.sin(rad, out=vals[2 + k3 : 2 + 2 * k3])
        np.negative(sin, out=vals[2 + 2 * k3 :])
        e = vals[self.gather_levels].reshape(-1, 3, 3, 3)
        out = e[:, 0] @ e[:, 1] @ e[:, 2]
        local = self.template.copy()
        if self.pre_levels is None:
            local[:, :3, :3] = out
        else:
            pre = self.pre_levels
            local[:, :3, :3] = pre @ out @ pre.transpose(0, 2, 1)
        local[0, self.root_axes, 3] = self.root_template + row[self.root_columns]
        world = np.empty_like(local)
        world[: self.n_roots] = local[: self.n_roots]
        for lo, hi, par in self.levels_one:
            np.matmul(world[par], local[lo:hi], out=world[lo:hi])
        return world

    def world(self, block: np.ndarray) -> np.ndarray:
        """World transforms (n, J, 4, 4) of channel rows, joints in level order (`where`)."""
        local = np.repeat(self.template[None], len(block), axis=0)
        local[..., :3, :3] = self.matrices(block, level_order=True)
        local[:, 0, self.root_axes, 3] += block[:, self.root_columns]
        world = np.empty_like(local)
        world[:, : self.n_roots] = local[:, : self.n_roots]
        # Homogeneous transforms: one matmul per tree level moves rotation and position.
        w, loc = (world[0], local[0]) if len(block) == 1 else (world, local)
        if len(block) == 1:  # the same products on (J, 4, 4) views: fewer indexing steps
            for lo, hi, par in self.levels:
                np.matmul(w[par], loc[lo:hi], out=w[lo:hi])
        else:
            for lo, hi, par in self.levels:
                np.matmul(w[:, par], loc[:, lo:hi], out=w[:, lo:hi])
        return world


def _as_slice(index: np.ndarray) -> np.ndarray | slice:
    """`index` as a slice when it is a run of consecutive integers (a view instead of a copy)."""
    if len(index) and np.array_equal(index, np.arange(index[0], index[0] + len(index))):
        return slice(int(index[0]), int(index[0]) + len(index))
    return index


_PLANS: dict[int, tuple[Skeleton, _RotationPlan]] = {}


def _plan(skeleton: Skeleton) -> _RotationPlan:
    cached = _PLANS.get(id(skeleton))
    if cached is None or cached[0] is not skeleton:
        cached = (skeleton, _RotationPlan(skeleton))
        _PLANS[id(skeleton)] = cached
    return cached[1]


def local_rotations(skeleton: Skeleton, channels: np.ndarray) -> np.ndarray:
    """Local rotation matrices (n_frames, n_joints, 3, 3) from channel values."""
    channels = np.atleast_2d(np.asarray(channels, dtype=np.float64))
    plan = _plan(skeleton)
    out = np.empty((len(channels), skeleton.n_joints, 3, 3))
    for lo in range(0, len(channels), 4096):  # bounded temporaries: linear in frames
        out[lo : lo + 4096] = plan.matrices(channels[lo : lo + 4096])
    return out


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
    if n == 1:
        return _fk_one(plan, channels[0])
    positions = np.empty((n, plan.n_points, 3))
    root_rotation = np.empty((n, 3, 3))
    j = skeleton.n_joints
    for lo in range(0, n, chunk):
        world = plan.world(channels[lo : lo + chunk])
        positions[lo : lo + chunk, :j] = world[..., :3, 3][:, plan.where]
        if plan.ends is not None:
            positions[lo : lo + chunk, j:] = (world[:, plan.where[plan.ends]]
                                              @ plan.end_offsets)[..., :3, 0]
        root_rotation[lo : lo + chunk] = world[:, 0, :3, :3]
    return FKResult(positions, root_rotation, plan.names)


def _fk_one(plan: _RotationPlan, row: np.ndarray) -> FKResult:
    """`forward_kinematics` of one frame (the same bits, fewer numpy calls)."""
    world = plan.world_one(row)
    j = plan.skeleton.n_joints
    positions = np.empty((1, plan.n_points, 3))
    positions[0, :j] = world.reshape(-1).take(plan.translations).reshape(j, 3)
    if plan.ends is not None:
        positions[0, j:] = (world[plan.where[plan.ends]] @ plan.end_offsets)[..., :3, 0]
    return FKResult(positions, world[None, 0, :3, :3].copy(), plan.names)


def joint_heights(skeleton: Skeleton, channels: np.ndarray, joints: tuple[int, ...]) -> np.ndarray:
    """World Y (n, len(joints)) of some joints, composing only their ancestors: the same bits
    as `forward_kinematics` (the same product per joint), for less work."""
    sub = _plan(skeleton).subplan(joints)
    channels = np.atleast_2d(np.asarray(channels, dtype=np.float64))
    if len(channels) == 1:
        return sub.world_one(channels[0])[None, sub.where[list(joints)], 1, 3]
    world = sub.world(channels)
    return world[:, sub.where[list(joints)], 1, 3]


def pelvis_frame(fk: FKResult, pelvis: int = 0) -> np.ndarray:
    """Positions in the pelvis-fixed frame: R_pelvis^T (p - p_pelvis), (n, points, 3)."""
    return to_pelvis(fk.positions, fk.positions[:, pelvis], fk.root_rotation)


def to_pelvis(points: np.ndarray, pelvis: np.ndarray, root_rotation: np.ndarray) -> np.ndarray:
    """R^T (p - p_pelvis) of points (n, k, 3), pelvis positions (n, 3), rotations (n, 3, 3)."""
    return (points - pelvis[:, None]) @ root_rotation


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
