"""Forward kinematics: one compiled kernel (`_fk_kernel`) for every frame count, so one
frame (online), a block and a whole clip (offline) give the same bits."""

from __future__ import annotations

import math
from collections.abc import Iterable
from typing import cast

import numpy as np

from .jit import kernel, warmer
from .motion import POSITION_CHANNELS, ROTATION_CHANNELS, Motion, Skeleton

__all__ = ["euler_matrices", "local_rotations", "forward_kinematics", "FKResult", "body_height",
           "pelvis_frame", "point_names", "skeleton_defect", "MAX_DEPTH", "MIN_BODY_HEIGHT",
           "root_relative_joints", "to_pelvis", "joint_heights", "fk_points", "warm_kinematics"]

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


def _ancestors(parents: list[int], joints: list[int]) -> np.ndarray:
    """Mask of `joints` and all their ancestors."""
    keep = np.zeros(len(parents), dtype=bool)
    for q in joints:
        while q >= 0 and not keep[q]:
            keep[q] = True
            q = parents[q]
    return keep


class _Plan:
    """A skeleton's FK as flat arrays for `_fk_kernel`: the joints to compose (all, or some
    points' ancestors only) in an order where every parent comes before its children.

    `ip` (int64): a header `[K, E, root row, root X/Y/Z position columns (-1: none)]`, then
    per joint row `[joint, parent row (-1: a root), n rotations, 3 columns, 3 axes, has
    pre-rotation]`, then per end site `[parent row, FK point]`. `fp` (float64): each row's
    offset (3), pre-rotation (9, identity if none), then each end site's offset (3).
    """

    def __init__(self, skeleton: Skeleton, points: tuple[int, ...] | None = None) -> None:
        assert skeleton.rotation_order is not None and skeleton.pre_rotations is not None
        j = skeleton.n_joints
        parents = list(skeleton.parents)
        ends = sorted(skeleton.end_sites)
        if points is None:
            keep, kept_ends = np.ones(j, dtype=bool), list(range(len(ends)))
        else:
            kept_ends = sorted({p - j for p in points if p >= j})
            keep = _ancestors(parents, [p for p in points if p < j]
                              + [ends[e] for e in kept_ends])
        order = [q for q in _parents_first(parents) if keep[q]]
        row = {q: r for r, q in enumerate(order)}
        pos = [skeleton.channel_index(0, c) for c in POSITION_CHANNELS]
        header = [len(order), len(kept_ends), row.get(0, -1)] + [
            -1 if c is None else c for c in pos]
        ip: list[int] = list(header)
        fp: list[float] = []
        for q in order:
            names = skeleton.rotation_order[q]
            # every name of rotation_order is one of the joint's channels
            cols = cast(list[int], [skeleton.channel_index(q, c) for c in names])
            axes = [_AXIS[c] for c in names]
            pre = skeleton.pre_rotations[q]
            ip += [q, row.get(parents[q], -1), len(names), *(cols + [0] * (3 - len(cols))),
                   *(axes + [0] * (3 - len(axes))), int(pre is not None)]
        for q in order:
            fp += list(skeleton.offsets[q])
        for q in order:
            pre = skeleton.pre_rotations[q]
            fp += list(np.eye(3).ravel() if pre is None else np.asarray(pre).ravel())
        for e in kept_ends:
            ip += [row[ends[e]], j + e]
            fp += list(skeleton.end_sites[ends[e]])
        self.ip = np.array(ip, dtype=np.int64)
        self.fp = np.array(fp, dtype=np.float64)
        self.n_points = j + len(ends)
        self.names = point_names(skeleton)
        self.skeleton = skeleton
        # the FK points this plan sets: its joints and end sites
        self.valid = frozenset(order) | frozenset(j + e for e in kept_ends)
        self._subplans: dict[frozenset[int], _Plan] = {}

    def subplan(self, points: frozenset[int]) -> _Plan:
        """The plan for some FK points, their ancestors and the root only (cached)."""
        got = self._subplans.get(points)
        if got is None:
            got = self._subplans[points] = _Plan(self.skeleton, tuple(sorted({*points, 0})))
        return got


@kernel
def _local_rotation(row: np.ndarray, ip: np.ndarray, fp: np.ndarray,
                    k: int) -> tuple[float, ...]:
    """Local rotation (row-major 9-tuple) of plan row `k` from one channel row: the Euler
    rotations composed left to right, column by column, then C·R·Cᵀ for a pre-rotation."""
    r = 6 + 10 * k
    m00, m01, m02, m10, m11, m12, m20, m21, m22 = 1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0
    d2r = np.pi / 180.0
    for q in range(ip[r + 2]):
        a = row[ip[r + 3 + q]] * d2r
        c, s = math.cos(a), math.sin(a)
        axis = ip[r + 6 + q]
        # M @ A: A (about `axis`) mixes two columns u, v: u' = c u + s v, v' = c v - s u.
        if axis == 0:
            m01, m02 = c * m01 + s * m02, c * m02 - s * m01
            m11, m12 = c * m11 + s * m12, c * m12 - s * m11
            m21, m22 = c * m21 + s * m22, c * m22 - s * m21
        elif axis == 1:
            m02, m00 = c * m02 + s * m00, c * m00 - s * m02
            m12, m10 = c * m12 + s * m10, c * m10 - s * m12
            m22, m20 = c * m22 + s * m20, c * m20 - s * m22
        else:
            m00, m01 = c * m00 + s * m01, c * m01 - s * m00
            m10, m11 = c * m10 + s * m11, c * m11 - s * m10
            m20, m21 = c * m20 + s * m21, c * m21 - s * m20
    if ip[r + 9]:
        b = 3 * ip[0] + 9 * k
        p00, p01, p02 = fp[b], fp[b + 1], fp[b + 2]
        p10, p11, p12 = fp[b + 3], fp[b + 4], fp[b + 5]
        p20, p21, p22 = fp[b + 6], fp[b + 7], fp[b + 8]
        # T = P M, then T Pᵀ
        t00 = p00 * m00 + p01 * m10 + p02 * m20
        t01 = p00 * m01 + p01 * m11 + p02 * m21
        t02 = p00 * m02 + p01 * m12 + p02 * m22
        t10 = p10 * m00 + p11 * m10 + p12 * m20
        t11 = p10 * m01 + p11 * m11 + p12 * m21
        t12 = p10 * m02 + p11 * m12 + p12 * m22
        t20 = p20 * m00 + p21 * m10 + p22 * m20
        t21 = p20 * m01 + p21 * m11 + p22 * m21
        t22 = p20 * m02 + p21 * m12 + p22 * m22
        m00 = t00 * p00 + t01 * p01 + t02 * p02
        m01 = t00 * p10 + t01 * p11 + t02 * p12
        m02 = t00 * p20 + t01 * p21 + t02 * p22
        m10 = t10 * p00 + t11 * p01 + t12 * p02
        m11 = t10 * p10 + t11 * p11 + t12 * p12
        m12 = t10 * p20 + t11 * p21 + t12 * p22
        m20 = t20 * p00 + t21 * p01 + t22 * p02
        m21 = t20 * p10 + t21 * p11 + t22 * p12
        m22 = t20 * p20 + t21 * p21 + t22 * p22
    return m00, m01, m02, m10, m11, m12, m20, m21, m22


@kernel
def _fk_kernel(channels: np.ndarray, ip: np.ndarray, fp: np.ndarray, pos: np.ndarray,
               rot: np.ndarray) -> None:
    """FK of every channel row (n, C) by a plan (`_Plan`): world positions of the plan's
    joints and end sites into `pos` (n, points, 3) (other points untouched), the root's world
    rotation into `rot` (n, 3, 3) unless it has no rows. Each frame, each joint: the same
    arithmetic whatever n or the plan (so one frame, a block and a sub-plan agree bitwise)."""
    nk, ne, root = ip[0], ip[1], ip[2]
    w = np.empty((nk, 9))
    t = np.empty((nk, 3))
    e0 = 6 + 10 * nk
    for f in range(channels.shape[0]):
        row = channels[f]
        for k in range(nk):
            r = 6 + 10 * k
            m = _local_rotation(row, ip, fp, k)
            o0, o1, o2 = fp[3 * k], fp[3 * k + 1], fp[3 * k + 2]
            par = ip[r + 1]
            if par < 0:
                for i in range(9):
                    w[k, i] = m[i]
                if ip[r] == 0:  # the root's position channels move it
                    if ip[3] >= 0:
                        o0 = o0 + row[ip[3]]
                    if ip[4] >= 0:
                        o1 = o1 + row[ip[4]]
                    if ip[5] >= 0:
                        o2 = o2 + row[ip[5]]
                t[k, 0], t[k, 1], t[k, 2] = o0, o1, o2
            else:
                for i in range(3):
                    a0, a1, a2 = w[par, 3 * i], w[par, 3 * i + 1], w[par, 3 * i + 2]
                    w[k, 3 * i] = a0 * m[0] + a1 * m[3] + a2 * m[6]
                    w[k, 3 * i + 1] = a0 * m[1] + a1 * m[4] + a2 * m[7]
                    w[k, 3 * i + 2] = a0 * m[2] + a1 * m[5] + a2 * m[8]
                    t[k, i] = t[par, i] + (a0 * o0 + a1 * o1 + a2 * o2)
            q = ip[r]
            pos[f, q, 0], pos[f, q, 1], pos[f, q, 2] = t[k, 0], t[k, 1], t[k, 2]
        for e in range(ne):
            par, q = ip[e0 + 2 * e], ip[e0 + 2 * e + 1]
            b = 12 * nk + 3 * e
            o0, o1, o2 = fp[b], fp[b + 1], fp[b + 2]
            for i in range(3):
                pos[f, q, i] = t[par, i] + (w[par, 3 * i] * o0 + w[par, 3 * i + 1] * o1
                                            + w[par, 3 * i + 2] * o2)
        if rot.shape[0] and root >= 0:
            for i in range(3):
                for c in range(3):
                    rot[f, i, c] = w[root, 3 * i + c]


@kernel
def _local_kernel(channels: np.ndarray, ip: np.ndarray, fp: np.ndarray,
                  out: np.ndarray) -> None:
    """Local rotations (n, J, 3, 3) of every joint of a plan (`_local_rotation`)."""
    for f in range(channels.shape[0]):
        for k in range(ip[0]):
            m = _local_rotation(channels[f], ip, fp, k)
            q = ip[6 + 10 * k]
            for i in range(3):
                for c in range(3):
                    out[f, q, i, c] = m[3 * i + c]


@kernel
def _pelvis_kernel(pos: np.ndarray, rot: np.ndarray, pelvis: int, points: np.ndarray,
                   out: np.ndarray) -> None:
    """R^T (p - p_pelvis) of some FK points of every frame into `out` (n, len(points), 3)."""
    for f in range(pos.shape[0]):
        x, y, z = pos[f, pelvis, 0], pos[f, pelvis, 1], pos[f, pelvis, 2]
        for q in range(points.shape[0]):
            p = points[q]
            dx, dy, dz = pos[f, p, 0] - x, pos[f, p, 1] - y, pos[f, p, 2] - z
            for i in range(3):
                out[f, q, i] = dx * rot[f, 0, i] + dy * rot[f, 1, i] + dz * rot[f, 2, i]


_PLANS: dict[int, tuple[Skeleton, _Plan]] = {}


def _plan(skeleton: Skeleton) -> _Plan:
    cached = _PLANS.get(id(skeleton))
    if cached is None or cached[0] is not skeleton:
        cached = (skeleton, _Plan(skeleton))
        _PLANS[id(skeleton)] = cached
    return cached[1]


def _rows(channels: np.ndarray) -> np.ndarray:
    """Channel rows as the kernels take them: 2-D, float64, C order (a copy only if not)."""
    if (type(channels) is np.ndarray and channels.ndim == 2 and channels.dtype == np.float64
            and channels.flags.c_contiguous):
        return channels
    return np.ascontiguousarray(np.atleast_2d(np.asarray(channels, dtype=np.float64)))


def local_rotations(skeleton: Skeleton, channels: np.ndarray) -> np.ndarray:
    """Local rotation matrices (n_frames, n_joints, 3, 3) from channel values."""
    channels = _rows(channels)
    plan = _plan(skeleton)
    out = np.empty((len(channels), skeleton.n_joints, 3, 3))
    _local_kernel(channels, plan.ip, plan.fp, out)
    return out


def point_names(skeleton: Skeleton) -> list[str]:
    """Names of the FK points: every joint, then every end site as `<joint>_End`."""
    return skeleton.names + [f"{skeleton.names[j]}_End" for j in sorted(skeleton.end_sites)]


class FKResult:
    """World positions (n_frames, n_points, 3) of joints then end sites, and root rotations.

    A partial result (`fk_points`) holds only `valid` points' rows; the others are garbage."""

    def __init__(self, positions: np.ndarray, root_rotation: np.ndarray, names: list[str],
                 valid: frozenset[int] | None = None):
        self.positions = positions
        self.root_rotation = root_rotation
        self.names = names
        self.valid = valid  # None: every point


def forward_kinematics(skeleton: Skeleton, channels: np.ndarray, chunk: int = 4096) -> FKResult:
    """World positions of every joint and end site for every frame (one compiled pass,
    written into the result: no temporaries).

    Frames are independent and always go through the same arithmetic, so any split of a
    stream into blocks gives bit-identical results: offline and online features agree exactly.
    """
    channels = _rows(channels)
    plan = _plan(skeleton)
    n = len(channels)
    positions = np.empty((n, plan.n_points, 3))
    root_rotation = np.empty((n, 3, 3))
    if n <= chunk:
        _fk_kernel(channels, plan.ip, plan.fp, positions, root_rotation)
    else:  # the same bits whatever the split (frames are independent)
        for lo in range(0, n, max(int(chunk), 1)):
            hi = lo + chunk
            _fk_kernel(channels[lo:hi], plan.ip, plan.fp, positions[lo:hi],
                       root_rotation[lo:hi])
    return FKResult(positions, root_rotation, plan.names)


def fk_points(skeleton: Skeleton, channels: np.ndarray, points: Iterable[int]) -> FKResult:
    """`forward_kinematics` of some FK points only, composing just their ancestors (and the
    root, for `root_rotation`): the same bits for those points. The result has every point's
    row; only `valid` ones (the points and their ancestors) are set."""
    channels = _rows(channels)
    plan = _plan(skeleton).subplan(points if isinstance(points, frozenset) else frozenset(
        int(p) for p in points))
    positions = np.empty((len(channels), plan.n_points, 3))
    root_rotation = np.empty((len(channels), 3, 3))
    _fk_kernel(channels, plan.ip, plan.fp, positions, root_rotation)
    return FKResult(positions, root_rotation, plan.names, plan.valid)


def joint_heights(skeleton: Skeleton, channels: np.ndarray, joints: tuple[int, ...]) -> np.ndarray:
    """World Y (n, len(joints)) of some joints, composing only their ancestors: the same bits
    as `forward_kinematics` (the same kernel and arithmetic per joint), for less work."""
    return fk_points(skeleton, channels, joints).positions[:, list(joints), 1]


def pelvis_frame(fk: FKResult, pelvis: int = 0, points: np.ndarray | None = None) -> np.ndarray:
    """Positions in the pelvis-fixed frame: R_pelvis^T (p - p_pelvis), (n, points, 3); every
    FK point, or only `points` (the same bits for each)."""
    points = _every_point(fk.positions.shape[1]) if points is None else np.asarray(
        points, dtype=np.int64)
    out = np.empty((fk.positions.shape[0], len(points), 3))
    _pelvis_kernel(fk.positions, fk.root_rotation, int(pelvis), points, out)
    return out


def _every_point(n: int, _cache: dict[int, np.ndarray] = {}) -> np.ndarray:  # noqa: B006
    got = _cache.get(n)
    if got is None:
        got = _cache[n] = np.arange(n, dtype=np.int64)  # writable: one kernel signature
    return got


def to_pelvis(points: np.ndarray, pelvis: np.ndarray, root_rotation: np.ndarray) -> np.ndarray:
    """R^T (p - p_pelvis) of points (n, k, 3), pelvis positions (n, 3), rotations (n, 3, 3)
    (numpy; `pelvis_frame` is the compiled form the features use)."""
    local: np.ndarray = (points - pelvis[:, None]) @ root_rotation
    return local


def root_relative_joints(positions: np.ndarray, n_joints: int) -> np.ndarray:
    """Joint positions (ROOT and JOINT, not End Sites) minus the root's, world orientation:
    the points of Halit 2010 eq. 4.1, (n, n_joints, 3)."""
    joints = positions[:, :n_joints]
    relative: np.ndarray = joints - joints[:, :1]
    return relative


def body_height(skeleton: Skeleton) -> float:
    """Height of the skeleton in its zero pose (offsets only): top minus bottom, file units.
    Every rotation is the identity there, so points are sums of offsets (FK's bits; no
    compiled code on the file-reading path)."""
    points = np.zeros((skeleton.n_joints, 3))
    for j in _parents_first(skeleton.parents):
        p = skeleton.parents[j]
        points[j] = skeleton.offsets[j] if p < 0 else points[p] + skeleton.offsets[j]
    ends = [points[j] + np.asarray(o, dtype=np.float64) for j, o in sorted(
        skeleton.end_sites.items())]
    pts = np.concatenate([points, np.reshape(ends, (-1, 3))])
    return float(pts[:, 1].max() - pts[:, 1].min())


def _parents_first(parents: list[int]) -> list[int]:
    """Joint indices ordered by depth (every parent before its children)."""
    depth = [0] * len(parents)
    for j, p in enumerate(parents):  # a parent's index is below its children's
        depth[j] = 0 if p < 0 else depth[p] + 1
    return sorted(range(len(parents)), key=lambda j: depth[j])


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


@warmer
def warm_kinematics() -> None:
    """Compile (or load from the cache) the FK and pelvis-frame kernels."""
    from .motion import Skeleton

    skel = Skeleton(["root", "leg"], [-1, 0], np.array([[0.0, 0.0, 0.0], [0.0, -1.0, 0.0]]),
                    [["Xposition", "Yposition", "Zposition", "Zrotation", "Xrotation",
                      "Yrotation"], ["Zrotation", "Xrotation", "Yrotation"]],
                    {1: np.array([0.0, -1.0, 0.0])})
    fk = forward_kinematics(skel, np.zeros((1, skel.n_channels)))
    pelvis_frame(fk, 0, np.array([1]))
    local_rotations(skel, np.zeros((1, skel.n_channels)))
