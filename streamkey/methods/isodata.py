"""ISODATA clustering keyframes with adaptive thresholds — Zhang et al. 2013, "An efficient
method of key-frame extraction based on a cluster algorithm" (an offline baseline).

Offline: `extract(motion)`. The paper's plain-text rendering lost most formulas; what
survives (eq. 4-6: O_s, D_T, I) and the prose are followed, and this module settles the rest:

- Pose vector (the paper's eq. 1 uses Euler angles): per joint, the local rotation of its
  rotation channels (BVH/AMC order, ASF axis included) as a unit quaternion, signs made
  continuous over time, scaled by 360/pi so that the Euclidean distance between two joint
  quaternions (2 sin(theta/4), theta the angle between the rotations) reads as degrees for
  small angles. Why not Euclidean on Euler: the CMU clips hold equivalent-triple jumps (a
  joint near gimbal lock switches to the other Euler solution; unwrapping cannot fix it) that
  look like 100-300 degree steps between adjacent frames; quaternions see the true angle.
  ISODATA needs cluster centres and per-axis deviations, so the distance stays Euclidean in a
  vector space (the quaternion components) rather than a pure geodesic.
- Weights (eq. 1, "the parent joint is important"): w_t = 1 / (1 + depth_t), depth 0 for the
  root, so the root and pelvis count most and fingers least.
  D(F_i, F_j) = sqrt(sum_t w_t |F_i^t - F_j^t|^2) (eq. 5 has this form for D_T).
- Step 1, adaptive threshold: the adjacent-frame distances Dif are split into two classes at
  the cut (in sorted order) of minimum dispersion delta^2 = the sum of the two classes'
  squared deviations about their means (Otsu's within-class criterion; the unweighted sum of
  the two variances degenerates to a one-element class on every shared clip). D_T is the
  smallest distance of the high class (the paper's walk: minimum at 36, 35 values above D_T,
  37 initial classes), (F_i, F_i+1) the pair it belongs to, O_c = D_T, O_s = sum_t
  |F_i,t - F_i+1,t| (eq. 4; L1 over every pose coordinate).
- Glitch guard (not in the paper): distances above the fence Q3 + 10 IQR (far beyond Tukey's
  far-out fence, Q3 + 3 IQR, so that a genuine minority of fast frames stays in) take no
  part in the two-class cut (`outlier_fence` = 10; None = the paper's plain cut). Most shared CMU
  clips hold single-frame pose glitches (thumb flips of ~170 degrees, a hip flip in 05_18,
  a second zero frame in 07_12) whose 50-110 degree steps dwarf real motion (median 1-5);
  the plain cut then isolates them as the high class, D_T becomes ~50, no initial class
  breaks, O_s blocks every split, and 13 of the 35 clips end with 0.5-0.9 % keyframes that
  no parameter can change. Glitch frames still start classes (their distance is >= D_T).
- Initial classes: frames in order; frame f starts a new class when D(F_f-1, F_f) >= D_T or
  D(F_f, centre of the current class) >= D_T (the paper's two rules).
- Parameters from the motion (the K formula is lost; the text says it comes from the frame
  rate and length and that O_N = 25 corresponds to it at 120 Hz; the paper's compression ratios,
  3.1-4.4 %, fit one cluster per ~25 frames): with c = `cluster_seconds` (default 25/120 s),
  K = max(1, round(N / (c fps))), O_N = max(2, round(c fps)), I = ceil(N / (2 K)) (eq. 6),
  L = `max_merges` (default unlimited; each class merges at most once per iteration, so an
  iteration at most halves the count, as the paper states).
- Classes stay runs of consecutive frames ("adjacent frames are dealt with ... in the order of
  the frames"): there is no nearest-centre reassignment. Iteration it = 1..I: split when the
  count < K/2, or it is odd and K/2 <= count <= 2K; else merge. Stop when K/2 <= count <= K
  (the expected number of clusters) or after I iterations or when an iteration changes
  nothing twice in a row.
- Split: a class whose dispersion (mean distance of its frames to its centre) exceeds the mean
  dispersion over all frames and whose largest per-coordinate standard deviation exceeds O_s,
  and that holds at least 2 O_N frames (classic ISODATA's guard), is cut in two at the frame
  that minimises the two halves' squared deviations (each half >= O_N frames).
- Merge: adjacent classes, scanned in frame order, merge when their centres are closer than
  O_c or either holds fewer than O_N frames.
- Dynamic thresholds: after every split or merge, the step-1 split is repeated on the distances
  between adjacent cluster centres; O_c becomes its D_T and O_s the L1 difference of that pair
  of centres (the paper: "changed dynamically after splitting or merging").
- Keyframe of a class: its frame nearest to the class centre (ties: earliest); score = the
  class size in frames.

Cost: the initial classes' frame loop and the prefix sums of the weighted poses are numba
kernels (`streamkey.jit`) with numpy's arithmetic (the same BLAS dot, the same running sums:
the same classes on every shared clip); prefix sums are stored every 8 rows and class centres
are made per block: at 100,000 frames the traced peak is 137 MB against 281 MB, and the CPU
time 0.93 s against 1.30 s (A/B on a loaded machine).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, cast

import numpy as np
from scipy.spatial.transform import Rotation

from ..errors import UsageError
from ..features import Features
from ..jit import kernel, warmer
from ..keyframes import Keyframes
from ..motion import Motion, Skeleton

__all__ = ["extract", "pose_vectors", "joint_weights", "min_dispersion_split",
           "initial_classes", "derived_parameters", "METHOD", "CLUSTER_SECONDS", "OUTLIER_FENCE"]

METHOD = "isodata"
CLUSTER_SECONDS = 25.0 / 120.0  # O_N = 25 frames at the paper's 120 Hz
OUTLIER_FENCE = 10.0  # far beyond Tukey's far-out fence (Q3 + 3 IQR): pose glitches only
CHUNK = 4096  # rows per block of full-length work: temporaries stay cache-sized
_STEP = 8  # rows between stored prefix sums


def joint_weights(skeleton: Skeleton) -> np.ndarray:
    """w_t = 1 / (1 + depth of joint t in the tree): parents outweigh their children."""
    depth = np.zeros(skeleton.n_joints)
    for j, p in enumerate(skeleton.parents):
        if p >= 0:
            depth[j] = depth[p] + 1
    return 1.0 / (1.0 + depth)


def _quat_mul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product of quaternions (4, ...) stored component-first (x, y, z, w)."""
    ax, ay, az, aw = a
    bx, by, bz, bw = b
    return np.array([aw * bx + ax * bw + ay * bz - az * by,
                     aw * by - ax * bz + ay * bw + az * bx,
                     aw * bz + ax * by - ay * bx + az * bw,
                     aw * bw - ax * bx - ay * by - az * bz])


def _turn(q: np.ndarray, axis: int, c: np.ndarray, s: np.ndarray) -> np.ndarray:
    """q * (s e_axis + c) for q component-first (4, ...)."""
    i, j = [(1, 2), (2, 0), (0, 1)][axis]
    out = np.empty_like(q)
    out[axis] = q[axis] * c + q[3] * s
    out[i] = q[i] * c + q[j] * s
    out[j] = q[j] * c - q[i] * s
    out[3] = q[3] * c - q[axis] * s
    return out


def local_quaternions(skeleton: Skeleton, channels: np.ndarray,
                      rotations_only: bool = False) -> np.ndarray:
    """Local joint rotations as unit quaternions (n, joints, 4), (x, y, z, w), straight from
    the Euler channels: the product of one half-angle quaternion per channel in the joint's
    order (the matrices' intrinsic product), conjugated by the ASF axis where there is one.
    With `rotations_only`, `channels` holds the columns `skeleton.rotation_columns()` only."""
    assert skeleton.rotation_order is not None and skeleton.pre_rotations is not None
    n, joints = len(channels), skeleton.n_joints
    where = {int(c): i for i, c in enumerate(skeleton.rotation_columns())}
    q = np.zeros((4, joints, n))  # component-first, frames last: joint rows are contiguous
    q[3] = 1.0
    for k in range(3):
        for axis, name in enumerate(("Xrotation", "Yrotation", "Zrotation")):
            idx = [j for j, order in enumerate(skeleton.rotation_order)
                   if len(order) > k and order[k] == name]
            if not idx:
                continue
            # `name` is one of joint j's channels (its rotation order)
            cols = cast(list[int], [skeleton.channel_index(j, name) for j in idx])
            if rotations_only:
                cols = [where[int(c)] for c in cols]
            half = np.radians(channels[:, cols].T)
            half *= 0.5
            c, s = np.cos(half), np.sin(half)
            if k == 0:  # identity * (s e_axis + c)
                q[axis, idx], q[3, idx] = s, c
            else:
                q[:, idx] = _turn(q[:, idx], axis, c, s)
    pre = [i for i, r in enumerate(skeleton.pre_rotations) if r is not None]
    if pre:
        p = Rotation.from_matrix(np.array([skeleton.pre_rotations[i] for i in pre])).as_quat()
        p = p.T[:, :, None]  # (4, len(pre), 1), component-first
        p_conj = p * np.array([-1.0, -1.0, -1.0, 1.0])[:, None, None]
        q[:, pre] = _quat_mul(_quat_mul(p, q[:, pre]), p_conj)
    return q.transpose(2, 1, 0).copy()


def pose_vectors(skeleton: Skeleton, channels: np.ndarray, chunk: int = 8192,
                 rotations_only: bool = False) -> np.ndarray:
    """Per-joint sign-continuous quaternions x 360/pi, (n, joints, 4) (module docstring).

    Computed `chunk` frames at a time (cache-sized temporaries); the sign of each chunk's
    first frame follows the previous chunk's last, so the split changes nothing.
    `rotations_only`: `channels` holds the rotation columns only (as `Features.rotations`)."""
    out = np.empty((len(channels), skeleton.n_joints, 4))
    previous = None
    for lo in range(0, len(channels), chunk):
        q = local_quaternions(skeleton, channels[lo : lo + chunk], rotations_only)
        if previous is None:
            q[0] *= np.where(q[0, :, 3:] < 0, -1.0, 1.0)
        else:
            q[0] *= np.where(np.einsum("jk,jk->j", q[0], previous) < 0, -1.0, 1.0)[:, None]
        flip = np.where(np.einsum("fjk,fjk->fj", q[1:], q[:-1]) < 0, -1.0, 1.0)
        q[1:] *= np.cumprod(flip, axis=0)[..., None]
        previous = q[-1].copy()
        np.multiply(q, 360.0 / np.pi, out=out[lo : lo + chunk])
    return out


def min_dispersion_split(d: np.ndarray, fence: float | None = None) -> tuple[int, float]:
    """Step 1: (index in `d` of the threshold value D_T, D_T) of the minimum-dispersion cut.

    `d` sorted descending is cut after T values so that the summed squared deviations of the
    two classes is least; D_T is the T-th largest value (the smallest of the high class).
    With `fence` = k, values above Q3 + k IQR (Tukey's far-out values: pose glitches) take
    no part in the cut.
    """
    use = np.flatnonzero(d <= _fence(d, fence))
    order = use[np.argsort(-d[use], kind="stable")]
    s = d[order]
    n = len(s)
    if n < 3:
        return int(order[0]), float(s[0])
    c1, c2 = np.cumsum(s), np.cumsum(s * s)
    t = np.arange(1, n)
    high = c2[t - 1] - c1[t - 1] ** 2 / t
    low = (c2[-1] - c2[t - 1]) - (c1[-1] - c1[t - 1]) ** 2 / (n - t)
    cut = int(t[np.argmin(high + low)])
    return int(order[cut - 1]), float(s[cut - 1])


def _fence(d: np.ndarray, k: float | None) -> float:
    """Tukey's upper fence Q3 + k IQR (inf without k or with fewer than 4 values)."""
    if k is None or len(d) < 4:
        return float("inf")
    q1, q3 = np.percentile(d, [25.0, 75.0])
    return float(q3 + k * (q3 - q1))


@kernel
def _initial_starts(x: np.ndarray, scale: np.ndarray, far: np.ndarray, d_t: float,
                    out: np.ndarray) -> int:
    """`initial_classes` compiled: class start rows into `out`, returns their count. The
    distance to the centre is the same BLAS dot product as numpy's `diff @ diff`."""
    n, d = x.shape
    total, diff, row = np.empty(d), np.empty(d), np.empty(d)
    count, m = 0, 0
    for f in range(n):
        for j in range(d):
            row[j] = x[f, j] * scale[j]
        if f > 0:
            for j in range(d):
                diff[j] = row[j] - total[j] / count
            if not (far[f - 1] or math.sqrt(np.dot(diff, diff)) >= d_t):
                for j in range(d):
                    total[j] += row[j]
                count += 1
                continue
        out[m] = f
        m += 1
        total[:] = row
        count = 1
    return m


@warmer
def _warm() -> None:
    """Compile (or load) the kernel on a tiny input."""
    x = np.arange(12.0).reshape(4, 3)
    _initial_starts(x, np.ones(3), np.zeros(3, dtype=np.bool_), 1.0, np.empty(4, np.int64))
    checkpoints = np.empty((3, 3))
    _prefix_checkpoints(x, np.ones(3), 2, checkpoints)
    _prefix_rows(x, np.ones(3), 2, checkpoints, np.array([0, 3]), np.empty((2, 3)))


def initial_classes(y: np.ndarray, adjacent: np.ndarray, d_t: float,
                    scale: np.ndarray | None = None) -> np.ndarray:
    """Start rows of the initial classes (the paper's two rules, frames in order).

    With `scale`, the pose vectors are the rows of `y` times `scale`."""
    if len(y) == 0:
        return np.zeros(1, dtype=np.int64)
    y = np.ascontiguousarray(y, dtype=np.float64)
    scale = np.ones(y.shape[1]) if scale is None else np.ascontiguousarray(scale, np.float64)
    out = np.empty(len(y), dtype=np.int64)
    m = _initial_starts(y, scale, np.asarray(adjacent >= d_t, dtype=np.bool_), float(d_t), out)
    return out[:m].copy()


def derived_parameters(n: int, fps: float, cluster_seconds: float) -> dict[str, int]:
    """K, O_N and I from the clip length and frame rate (module docstring, eq. 6)."""
    per = cluster_seconds * fps
    k = max(1, int(round(n / per)))
    return {"K": k, "O_N": max(2, int(round(per))), "I": int(np.ceil(n / (2 * k)))}


@dataclass
class _Classes:
    """Runs of frames [starts[i], starts[i+1]) and their statistics."""

    starts: np.ndarray
    n: int

    def sizes(self) -> np.ndarray:
        return np.diff(np.append(self.starts, self.n))

    def labels(self) -> np.ndarray:
        return np.repeat(np.arange(len(self.starts)), self.sizes())


def _centres(st: _Stats, starts: np.ndarray, ends: np.ndarray) -> np.ndarray:
    """Centres (weighted) of the runs [starts, ends) from the prefix sums."""
    result: np.ndarray = (st.prefix(ends) - st.prefix(starts)) / (ends - starts)[:, None]
    return result


def _centre_gaps(st: _Stats, cl: _Classes) -> np.ndarray:
    """Distance between the centres of adjacent classes (blocks of classes: cache-sized
    temporaries; row by row the same numbers as on all classes at once)."""
    starts, ends = cl.starts, np.append(cl.starts[1:], cl.n)
    out = np.empty(max(len(starts) - 1, 0))
    for lo in range(0, len(out), CHUNK):
        hi = min(len(starts), lo + CHUNK + 1)
        c = _centres(st, starts[lo:hi], ends[lo:hi])
        out[lo : hi - 1] = np.linalg.norm(np.diff(c, axis=0), axis=1)
    return out


@kernel
def _prefix_checkpoints(x: np.ndarray, scale: np.ndarray, step: int, out: np.ndarray) -> None:
    """out[q] = sum of the rows x[i] * scale, i < q step, added in row order (as `cumsum`)."""
    d = x.shape[1]
    total = np.zeros(d)
    out[0] = total
    for i in range(len(x)):
        for j in range(d):
            total[j] += x[i, j] * scale[j]
        if (i + 1) % step == 0:
            out[(i + 1) // step] = total


@kernel
def _prefix_rows(x: np.ndarray, scale: np.ndarray, step: int, checkpoints: np.ndarray,
                 idx: np.ndarray, out: np.ndarray) -> None:
    """out[r] = sum of the rows x[i] * scale, i < idx[r]: from the checkpoint below, the same
    additions in the same order as one running sum over every row."""
    for r in range(len(idx)):
        q = idx[r] // step
        out[r] = checkpoints[q]
        for i in range(q * step, idx[r]):
            for j in range(x.shape[1]):
                out[r, j] += x[i, j] * scale[j]


class _Stats:
    """Prefix sums of the weighted pose vectors y = x * scale for O(1) run statistics (y made
    block by block, never whole; the row prefix sums kept every `_STEP` rows and completed on
    demand: an eighth of the memory, the same bits); statistics of the plain ones (x) for the
    few classes that need them."""

    def __init__(self, x: np.ndarray, scale: np.ndarray) -> None:
        self.x, self.scale = np.ascontiguousarray(x), np.ascontiguousarray(scale)
        n = len(x)
        self.checkpoints = np.empty((n // _STEP + 1, x.shape[1]))
        _prefix_checkpoints(self.x, self.scale, _STEP, self.checkpoints)
        self.cyy = np.empty(n + 1)
        self.cyy[0] = 0.0
        for lo in range(0, n, CHUNK):
            hi = min(n, lo + CHUNK)
            y = self.y_rows(lo, hi)
            yy = np.einsum("ij,ij->i", y, y)
            yy[0] += self.cyy[lo]  # the running total enters the first row: one cumsum's sums
            np.cumsum(yy, out=self.cyy[lo + 1 : hi + 1])

    def prefix(self, idx: np.ndarray) -> np.ndarray:
        """Sums of the weighted rows before each of `idx` (len(idx) x columns)."""
        idx = np.ascontiguousarray(idx, dtype=np.int64)
        out = np.empty((len(idx), self.x.shape[1]))
        _prefix_rows(self.x, self.scale, _STEP, self.checkpoints, idx, out)
        return out

    def y_rows(self, lo: int, hi: int) -> np.ndarray:
        """Weighted pose vectors of rows [lo, hi) (a new array)."""
        result: np.ndarray = self.x[lo:hi] * self.scale
        return result

    def adjacent(self) -> np.ndarray:
        """Weighted distance of each frame to the next (n - 1,)."""
        n = len(self.x)
        out = np.empty(max(0, n - 1))
        for lo in range(0, n - 1, CHUNK):
            hi = min(n - 1, lo + CHUNK)
            out[lo:hi] = np.linalg.norm(np.diff(self.y_rows(lo, hi + 1), axis=0), axis=1)
        return out

    def sse(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        """Weighted squared deviations of rows [a, b) about their mean."""
        s = self.prefix(b) - self.prefix(a)
        result: np.ndarray = self.cyy[b] - self.cyy[a] - np.einsum("ij,ij->i", s, s) / (b - a)
        return result

    def x_mean(self, a: int, b: int) -> np.ndarray:
        """Mean of the plain pose vectors of rows [a, b)."""
        result: np.ndarray = self.x[a:b].sum(axis=0) / (b - a)
        return result

    def max_std(self, a: int, b: int) -> float:
        """Largest per-coordinate standard deviation of rows [a, b) (unweighted)."""
        block = self.x[a:b]
        mean = block.sum(axis=0) / (b - a)
        var = (block * block).sum(axis=0) / (b - a) - mean**2
        return float(np.sqrt(np.maximum(var, 0.0)).max())


def _dispersion(st: _Stats, cl: _Classes) -> np.ndarray:
    """Mean distance of each class's frames to its centre."""
    lab = cl.labels()
    dist = _centre_distances(st, cl, lab)
    result: np.ndarray = np.bincount(lab, dist) / cl.sizes()
    return result


def _centre_distances(st: _Stats, cl: _Classes, lab: np.ndarray) -> np.ndarray:
    """Distance of every frame to its class centre, in row chunks (cache-sized temporaries)."""
    ends = np.append(cl.starts[1:], cl.n)
    dist = np.empty(cl.n)
    for lo in range(0, cl.n, CHUNK):
        hi = min(cl.n, lo + CHUNK)
        a, b = lab[lo], lab[hi - 1] + 1  # the classes of these rows only
        centres = _centres(st, cl.starts[a:b], ends[a:b])
        dist[lo:hi] = np.linalg.norm(st.y_rows(lo, hi) - centres[lab[lo:hi] - a], axis=1)
    return dist


def _best_cut(st: _Stats, a: int, b: int, o_n: int) -> int:
    """Row c in [a + o_n, b - o_n] minimising SSE[a, c) + SSE[c, b)."""
    c = np.arange(a + o_n, b - o_n + 1)
    aa, bb = np.full(len(c), a), np.full(len(c), b)
    return int(c[np.argmin(st.sse(aa, c) + st.sse(c, bb))])


def _split(st: _Stats, cl: _Classes, o_s: float, o_n: int) -> _Classes:
    """ISODATA split rule on every class (module docstring)."""
    sizes = cl.sizes()
    a, b = cl.starts, cl.starts + sizes
    disp = _dispersion(st, cl)
    mean_disp = float(np.sum(disp * sizes) / cl.n)
    wide = np.flatnonzero((disp > mean_disp) & (sizes >= 2 * o_n))
    ok = [i for i in wide if st.max_std(int(a[i]), int(b[i])) > o_s]
    cuts = [_best_cut(st, int(a[i]), int(b[i]), o_n) for i in ok]
    return _Classes(np.sort(np.concatenate([cl.starts, np.array(cuts, dtype=np.int64)])), cl.n)


def _merge(st: _Stats, cl: _Classes, o_c: float, o_n: int, limit: int | None) -> _Classes:
    """ISODATA merge rule, adjacent pairs in frame order, each class at most once."""
    sizes = cl.sizes()
    close = _centre_gaps(st, cl) < o_c
    small = (sizes[:-1] < o_n) | (sizes[1:] < o_n)
    want = close | small
    keep = np.ones(len(cl.starts), dtype=bool)
    i, merged = 0, 0
    while i < len(want) and (limit is None or merged < limit):
        if want[i]:
            keep[i + 1] = False  # class i + 1 joins class i
            merged += 1
            i += 2
        else:
            i += 1
    return _Classes(cl.starts[keep], cl.n)


def _thresholds(st: _Stats, cl: _Classes, o_c: float, o_s: float,
                fence: float | None) -> tuple[float, float]:
    """Step 1 again on adjacent centre distances: new (O_c, O_s); kept below 3 classes."""
    if len(cl.starts) < 3:
        return o_c, o_s
    i, d_t = min_dispersion_split(_centre_gaps(st, cl), fence)
    ends = np.append(cl.starts[1:], cl.n)
    pair = [st.x_mean(int(cl.starts[k]), int(ends[k])) for k in (i, i + 1)]
    return d_t, float(np.abs(pair[1] - pair[0]).sum())


def _iterate(st: _Stats, cl: _Classes, p: dict[str, Any],
             log: Callable[[str], None] | None) -> tuple[_Classes, list[dict[str, Any]]]:
    k, o_n = p["K"], p["O_N"]
    o_c, o_s = p["O_c"], p["O_s"]
    history: list[dict[str, Any]] = []
    idle = 0
    for it in range(1, p["I"] + 1):
        m = len(cl.starts)
        if k / 2 <= m <= k or idle >= 2:
            break
        split = m < k / 2 or (it % 2 == 1 and m <= 2 * k)
        new = _split(st, cl, o_s, o_n) if split else _merge(st, cl, o_c, o_n, p["L"])
        idle = idle + 1 if len(new.starts) == m else 0
        cl = new
        o_c, o_s = _thresholds(st, cl, o_c, o_s, p["fence"])
        step = {"iteration": it, "action": "split" if split else "merge",
                "classes": len(cl.starts), "O_c": o_c, "O_s": o_s}
        history.append(step)
        if log is not None:
            log(f"isodata: iteration {it} {step['action']}: {m} -> {step['classes']} classes, "
                f"O_c={o_c:.3f} O_s={o_s:.3f}")
    return cl, history


def _keyframes(st: _Stats, cl: _Classes) -> np.ndarray:
    """Row of each class nearest to its centre (earliest on ties)."""
    lab = cl.labels()
    dist = _centre_distances(st, cl, lab)
    order = np.lexsort((np.arange(cl.n), dist, lab))
    first = np.searchsorted(lab[order], np.arange(len(cl.starts)))
    return np.sort(order[first])


def _check(cluster_seconds: float, max_merges: int | None, fence: float | None) -> None:
    if fence is not None and not (np.isfinite(fence) and fence >= 0):
        raise UsageError(f"isodata: outlier_fence must be >= 0 or None, got {fence!r}")
    if not (np.isfinite(cluster_seconds) and cluster_seconds > 0):
        raise UsageError(f"isodata: cluster_seconds must be > 0, got {cluster_seconds!r}")
    if max_merges is not None and (isinstance(max_merges, bool) or int(max_merges) != max_merges
                                   or max_merges < 1):
        raise UsageError(f"isodata: max_merges must be a positive integer, got {max_merges!r}")


def extract(motion: Motion, *, features: Features | None = None,
            cluster_seconds: float = CLUSTER_SECONDS, max_merges: int | None = None,
            outlier_fence: float | None = OUTLIER_FENCE, verbose: bool = False,
            log: Callable[[str], None] | None = None) -> Keyframes:
    """ISODATA keyframes of `motion` with thresholds derived from the motion (Zhang et al.).

    `cluster_seconds` is the expected cluster duration: smaller asks for more keyframes.
    The derived thresholds are in `info`; with `verbose`, they are also passed to `log`.
    """
    _check(cluster_seconds, max_merges, outlier_fence)
    first = motion.first_frame
    # Unwrapped rotations when the features are there: the same poses (module docstring).
    values = motion.channels[first:] if features is None else features.rotations[first:]
    n = len(values)
    params: dict[str, Any] = {"cluster_seconds": cluster_seconds, "max_merges": max_merges,
                              "outlier_fence": outlier_fence}
    if n < 3:
        return Keyframes(METHOD, np.arange(n) + first, np.ones(n), params, motion.n_frames, {})
    say = log if verbose else None
    q = pose_vectors(motion.skeleton, values, rotations_only=features is not None)
    w = joint_weights(motion.skeleton)
    x = q.reshape(n, -1)
    st = _Stats(x, np.repeat(np.sqrt(w), 4))
    adjacent = st.adjacent()
    pair, d_t = min_dispersion_split(adjacent, outlier_fence)
    p: dict[str, Any] = derived_parameters(n, motion.fps, cluster_seconds)
    p.update(fence=outlier_fence, D_T=d_t, O_c=d_t, O_s=float(np.abs(x[pair + 1] - x[pair]).sum()),
             L=max_merges, threshold_pair=(pair + first, pair + 1 + first))  # eq. 4-5
    cl = _Classes(initial_classes(x, adjacent, d_t, st.scale), n)
    p["initial_classes"] = len(cl.starts)
    if say is not None:
        say(f"isodata: N={n} K={p['K']} O_N={p['O_N']} I={p['I']} L={max_merges} "
            f"D_T=O_c={d_t:.3f} O_s={p['O_s']:.3f} initial classes={len(cl.starts)}")
    cl, history = _iterate(st, cl, p, say)
    last = history[-1] if history else {"O_c": d_t, "O_s": p["O_s"]}
    info = dict(p, history=history, final_classes=len(cl.starts), O_c_final=last["O_c"],
                O_s_final=last["O_s"], class_starts=cl.starts + first, weights=w)
    return Keyframes(METHOD, _keyframes(st, cl) + first, cl.sizes().astype(np.float64), params,
                     motion.n_frames, info)
