"""Evaluation: reconstruction from keyframes, the error E of Halit's thesis (Halit 2010, "A
multi scale motion saliency method for keyframe extraction from motion capture sequences",
eq. 4.1) and PSNR (eq. 4.2), the F-measure of Miura et al. 2014 ("Adaptive keypose extraction
from motion capture data", §4.4) and the equal-count comparison (Halit Table 4.1).

Definitions this module settles:

- Reconstruction (`reconstruct`): between consecutive keyframes, joints with three rotation
  channels are interpolated by quaternion slerp (scipy `Rotation` converts Euler angles to
  quaternions and back; the slerp formula runs vectorised over every segment and every joint
  of one Euler order: scipy's `Slerp`, one call per joint, cost 4x more; the tests check the
  result against scipy rotation-vector slerp frame by frame); joints with one or two
  rotation channels (some ASF bones) and every position channel are interpolated linearly
  (a slerp between two-axis rotations leaves their two-axis family). The
  slerped rotation is written back as the Euler triple (of the two equivalent ones, each
  angle shifted by 360° multiples) nearest the linear interpolation of the unwrapped key
  angles, so Euler-space errors are not inflated by representation jumps. ``mode="linear"``
  interpolates every channel linearly (rotations unwrapped). Keyframes are copied exactly;
  the first and last captured frames are always keys of a reconstruction (every animation
  has them, so a method that does not pick them is not charged for holding a key backwards
  or forwards, and numbers compare with other tools' reconstructions); the reference frame
  (before `first_frame`) is copied and never scored.
- E (eq. 4.1): mean over captured frames and the skeleton's joints (ROOT and JOINT entries,
  not End Sites) of the squared distance between original and reconstructed root-relative
  positions (p - p_root, world orientation, so root rotation errors count, root translation
  does not), file units squared. The thesis divides by n x (number of dofs); we divide by
  n x (number of joints), the mean over frames and joints. Normalised:
  E / body_height^2 (squared body heights).
- PSNR (eq. 4.2): 20 log10(360 / sqrt(E_euler)), E_euler the mean over captured frames and
  rotation channels of the squared angle difference, wrapped to [-180, 180). Of the two
  equivalent Euler triples of a reconstructed 3-rotation joint, the one nearest the
  *original* channel values is scored (a near-gimbal joint is not charged for the branch).
- F-measure: one-to-one matching (`match_one_to_one`, a match needs |a - b| <= tol; the greedy
  sweep over both sorted lists gives a maximum matching for this interval structure); Miura's
  tolerance is 1/4 of the keypose interval (the median difference of the truth frames).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from .errors import UsageError
from .keyframes import Keyframes
from .kinematics import body_height, forward_kinematics, root_relative_joints
from .motion import Motion, Skeleton
from .signal import unwrap_degrees

__all__ = ["reconstruct", "error_e", "psnr", "match_one_to_one", "f_measure",
           "compare_at_equal_count", "error_curve", "Scores", "Evaluator", "METHODS", "MODES"]

MODES = ("slerp", "linear")
_SEQ = {"Xrotation": "X", "Yrotation": "Y", "Zrotation": "Z"}


def _key_rows(motion: Motion, frames: Keyframes | Iterable[int]) -> np.ndarray:
    """Keys of the reconstruction as sorted unique captured-row indices (0 =
    motion.first_frame): the given keyframes plus the first and last captured frames."""
    raw = frames.frames if isinstance(frames, Keyframes) else frames
    keys = np.unique(np.asarray(list(raw) if not isinstance(raw, np.ndarray) else raw,
                                dtype=np.int64))
    if len(keys) == 0:
        raise UsageError("need at least one keyframe")
    if keys[0] < motion.first_frame or keys[-1] >= motion.n_frames:
        raise UsageError(f"keyframes must lie in [{motion.first_frame}, {motion.n_frames - 1}]")
    ends = [0, motion.n_frames - 1 - motion.first_frame]
    return np.union1d(keys - motion.first_frame, ends)


def _segments(keys: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """For every row: left key, right key, interpolation weight (held outside the keys)."""
    rows = np.clip(np.arange(n), keys[0], keys[-1])
    seg = np.clip(np.searchsorted(keys, rows, side="right") - 1, 0, max(len(keys) - 2, 0))
    a = keys[seg]
    b = keys[np.minimum(seg + 1, len(keys) - 1)]
    t = np.where(b > a, (rows - a) / np.maximum(b - a, 1), 0.0)
    return a, b, t


def _lerp(x: np.ndarray, a: np.ndarray, b: np.ndarray, t: np.ndarray) -> np.ndarray:
    result: np.ndarray = x[a] + t[:, None] * (x[b] - x[a])
    return result


def _rotation_groups(skeleton: Skeleton) -> dict[str, np.ndarray]:
    """{scipy intrinsic sequence: (joints, 3) columns in that order} of 3-rotation joints."""
    groups: dict[str, list[list[int]]] = {}
    assert skeleton.rotation_order is not None
    for j, order in enumerate(skeleton.rotation_order):
        if len(order) == 3 and len(set(order)) == 3:
            cols = [skeleton.channel_index(j, c) for c in order]
            groups.setdefault("".join(_SEQ[c] for c in order), []).append(
                [int(c) for c in cols if c is not None])
    return {seq: np.array(cols, dtype=np.int64) for seq, cols in groups.items()}


def _slerp(q0: np.ndarray, q1: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Quaternion slerp along the shorter arc, rows (..., 4), weights t broadcast (..., 1)."""
    dot = np.sum(q0 * q1, axis=-1, keepdims=True)
    q1 = np.where(dot < 0.0, -q1, q1)
    theta = np.arccos(np.clip(np.abs(dot), 0.0, 1.0))
    sin = np.sin(theta)
    small = sin < 1e-9
    safe = np.where(small, 1.0, sin)
    w0 = np.where(small, 1.0 - t, np.sin((1.0 - t) * theta) / safe)
    w1 = np.where(small, t, np.sin(t * theta) / safe)
    q = w0 * q0 + w1 * q1
    result: np.ndarray = q / np.linalg.norm(q, axis=-1, keepdims=True)
    return result


def _slerp_joints(x: np.ndarray, seq: str, cols: np.ndarray, a: np.ndarray, b: np.ndarray,
                  t: np.ndarray, ref: np.ndarray) -> np.ndarray:
    """Slerped Euler angles (n, joints, 3) of the joints `cols` (all of one sequence)."""
    keys = np.unique(np.concatenate([a, b]))
    nk, nj = len(keys), len(cols)
    quat = Rotation.from_euler(seq, x[keys][:, cols].reshape(-1, 3), degrees=True).as_quat()
    quat = quat.reshape(nk, nj, 4)
    pos = np.searchsorted(keys, a), np.searchsorted(keys, b)
    q = _slerp(quat[pos[0]], quat[pos[1]], t[:, None, None])
    euler = Rotation.from_quat(q.reshape(-1, 4)).as_euler(seq, degrees=True)
    return _nearest_euler(euler, ref.reshape(-1, 3)).reshape(len(x), nj, 3)


def _nearest_euler(euler: np.ndarray, ref: np.ndarray) -> np.ndarray:
    """Of the two Tait-Bryan triples of each rotation, shifted by 360° multiples, the one
    nearest `ref` (degrees, rows)."""
    alt = euler + np.array([180.0, 0.0, 180.0])
    alt[:, 1] = 180.0 - euler[:, 1]  # R_a(α+180) R_b(180-β) R_c(γ+180) = R_a(α) R_b(β) R_c(γ)
    one, two = (c + 360.0 * np.round((ref - c) / 360.0) for c in (euler, alt))
    closer = np.sum((two - ref) ** 2, axis=1) < np.sum((one - ref) ** 2, axis=1)
    result: np.ndarray = np.where(closer[:, None], two, one)
    return result


def _unwrapped(motion: Motion) -> np.ndarray:
    """Captured rows of the channels with rotations unwrapped."""
    x = motion.channels[motion.first_frame :].copy()
    rot = motion.skeleton.rotation_columns()
    x[:, rot] = unwrap_degrees(x[:, rot])
    return x


def reconstruct(motion: Motion, frames: Keyframes | Iterable[int], mode: str = "slerp",
                unwrapped: np.ndarray | None = None) -> np.ndarray:
    """Channels (n_frames x n_channels) rebuilt from the keyframes only (module docstring).

    `unwrapped` (captured rows, rotations unwrapped) may be passed to skip recomputing it.
    """
    if mode not in MODES:
        raise UsageError(f"mode must be one of {MODES}, got {mode!r}")
    keys = _key_rows(motion, frames)
    first = motion.first_frame
    x = _unwrapped(motion) if unwrapped is None else unwrapped
    a, b, t = _segments(keys, len(x))
    rec = _lerp(x, a, b, t)  # linear everywhere; slerp replaces 3-rotation joints below
    if mode == "slerp" and len(keys) > 1:
        for seq, cols in _rotation_groups(motion.skeleton).items():
            rec[:, cols] = _slerp_joints(x, seq, cols, a, b, t, rec[:, cols])
    out = motion.channels.copy()
    out[first:] = rec
    out[first + keys] = motion.channels[first + keys]  # keyframes exactly as captured
    return out


class Evaluator:
    """Scores keyframe sets of one motion; caches the original's FK (reuse for many sets)."""

    def __init__(self, motion: Motion) -> None:
        self.motion = motion
        self.first = motion.first_frame
        self.body_height = body_height(motion.skeleton)
        self.rotation_columns = motion.skeleton.rotation_columns()
        self._groups = _rotation_groups(motion.skeleton)
        self._original = self._relative(motion.channels)
        self._unwrapped = _unwrapped(motion)

    def _relative(self, channels: np.ndarray) -> np.ndarray:
        pos = forward_kinematics(self.motion.skeleton, channels[self.first :]).positions
        return root_relative_joints(pos, self.motion.skeleton.n_joints)

    def error_e(self, reconstructed: np.ndarray, normalised: bool = False) -> float:
        """Halit eq. 4.1 (file units^2), or divided by body height^2 when `normalised`."""
        diff = self._relative(reconstructed) - self._original
        e = float(np.mean(np.sum(diff * diff, axis=-1)))
        return e / self.body_height**2 if normalised else e

    def euler_mse(self, reconstructed: np.ndarray) -> float:
        """Mean squared wrapped angle difference (degrees^2) over rotation channels, each
        3-rotation joint taken as its Euler triple nearest the original."""
        cols = self.rotation_columns
        orig = self.motion.channels[self.first :]
        rec = reconstructed[self.first :].copy()
        for group in self._groups.values():
            rec[:, group] = _nearest_euler(rec[:, group].reshape(-1, 3),
                                           orig[:, group].reshape(-1, 3)).reshape(
                len(rec), -1, 3)
        d = rec[:, cols] - orig[:, cols]
        d = np.mod(d + 180.0, 360.0) - 180.0
        return float(np.mean(d * d))

    def psnr(self, reconstructed: np.ndarray) -> float:
        """Halit eq. 4.2 with MAX = 360 degrees (inf for a perfect reconstruction)."""
        e = self.euler_mse(reconstructed)
        return float("inf") if e == 0.0 else float(20.0 * np.log10(360.0 / np.sqrt(e)))

    def score(self, frames: Keyframes | Iterable[int], mode: str = "slerp") -> Scores:
        """Reconstruct from `frames` and score it."""
        rec = reconstruct(self.motion, frames, mode, self._unwrapped)
        e = self.error_e(rec)
        return Scores(len(_key_rows(self.motion, frames)), e, e / self.body_height**2,
                      self.psnr(rec))


@dataclass(frozen=True)
class Scores:
    """Keys of the reconstruction (ends included), E (eq. 4.1), E / body height^2, PSNR
    (eq. 4.2, dB)."""

    count: int
    error: float
    error_normalised: float
    psnr: float


def error_e(motion: Motion, reconstructed: np.ndarray, *, normalised: bool = False) -> float:
    """Halit eq. 4.1: mean squared root-relative joint distance over captured frames."""
    return Evaluator(motion).error_e(reconstructed, normalised)


def psnr(motion: Motion, reconstructed: np.ndarray) -> float:
    """Halit eq. 4.2: PSNR in Euler space (MAX = 360 degrees) over captured frames."""
    return Evaluator(motion).psnr(reconstructed)


def _prf(tp: int, n_found: int, n_truth: int) -> tuple[float, float, float]:
    precision = tp / n_found if n_found else 1.0
    recall = tp / n_truth if n_truth else 1.0
    f1 = 2 * precision * recall / (precision + recall) if precision + recall else 0.0
    return precision, recall, f1


def match_one_to_one(found: Sequence[int] | np.ndarray, truth: Sequence[int] | np.ndarray,
                     tol: float) -> tuple[int, float, float, float]:
    """Maximum one-to-one matching with |f - t| <= tol: (matches, precision, recall, F1).

    Empty lists count as perfect precision (nothing wrong found) / recall (nothing to find).
    """
    a = np.sort(np.asarray(found, dtype=np.float64))
    b = np.sort(np.asarray(truth, dtype=np.float64))
    i = j = tp = 0
    while i < len(a) and j < len(b):
        if a[i] - b[j] > tol:
            j += 1  # b[j] is too early for every later found frame too
        elif b[j] - a[i] > tol:
            i += 1
        else:
            tp, i, j = tp + 1, i + 1, j + 1
    return (tp, *_prf(tp, len(a), len(b)))


def f_measure(found: Sequence[int] | np.ndarray, truth: Sequence[int] | np.ndarray,
              tolerance: float | None = None) -> tuple[float, float, float]:
    """Miura §4.4: (precision, recall, F1); default tolerance 1/4 of the median truth interval."""
    truth_arr = np.sort(np.asarray(truth, dtype=np.float64))
    if tolerance is None:
        if len(truth_arr) < 2:
            raise UsageError("need two truth frames for the default tolerance (an interval)")
        tolerance = float(np.median(np.diff(truth_arr))) / 4.0
    return match_one_to_one(found, truth_arr, tolerance)[1:]


def _builtin_methods() -> dict[str, Callable[[Motion, int], Keyframes]]:
    from .methods import baselines, optimal, simplify

    return {
        "uniform": baselines.uniform,
        "decimation": lambda m, k: baselines.decimate(m, k, space="channels"),
        "simplification": lambda m, k: simplify.extract(m, count=k, space="channels"),
        "decimation_positions": lambda m, k: baselines.decimate(m, k, space="positions"),
        "simplification_positions": lambda m, k: simplify.extract(m, count=k, space="positions"),
        "optimal": lambda m, k: optimal.extract(m, count=k),
    }


METHODS = ("uniform", "decimation", "simplification", "decimation_positions",
           "simplification_positions")


def _resolve(methods: Mapping[str, Callable[[Motion, int], Keyframes]] | Sequence[str]
             ) -> dict[str, Callable[[Motion, int], Keyframes]]:
    if isinstance(methods, Mapping):
        return dict(methods)
    builtin = _builtin_methods()
    unknown = [m for m in methods if m not in builtin]
    if unknown:
        raise UsageError(f"unknown methods {unknown}; built-in: {list(builtin)}")
    return {m: builtin[m] for m in methods}


def compare_at_equal_count(motion: Motion,
                           methods: Mapping[str, Callable[[Motion, int], Keyframes]]
                           | Sequence[str], count: int,
                           mode: str = "slerp") -> dict[str, Scores]:
    """Halit Table 4.1: every method forced to `count` keyframes, scored the same way.

    `methods` maps a name to `f(motion, count) -> Keyframes`, or lists built-in names
    (`METHODS`).
    """
    ev = Evaluator(motion)
    out = {}
    for name, fn in _resolve(methods).items():
        keys = fn(motion, count)
        if len(keys) != count:
            raise UsageError(f"method {name!r} returned {len(keys)} keyframes, not {count}")
        out[name] = ev.score(keys, mode)
    return out


def error_curve(motion: Motion, counts: Sequence[int], methods: Sequence[str] = ("uniform",
                "decimation"), mode: str = "slerp") -> dict[str, list[Scores]]:
    """Scores of built-in methods (`METHODS`) at each keyframe count ("decimation" and
    "simplification" in channel space, the `_positions` ones in position space).

    Decimation and count-mode simplification are nested in K, so each runs once per space.
    """
    from .features import compute_features
    from .methods import baselines, simplify

    ev = Evaluator(motion)
    out: dict[str, list[Scores]] = {}
    for name in methods:
        if name not in METHODS:
            raise UsageError(f"unknown method {name!r}; built-in: {list(METHODS)}")
        space = "positions" if name.endswith("_positions") else "channels"
        feats = compute_features(motion) if space == "positions" else None
        x = simplify.curve(motion, space, feats)
        n = len(x)
        if name.startswith("decimation"):
            removed, _ = baselines.decimation_order(x, min(counts))
            sets = [np.setdiff1d(np.arange(n), removed[: n - k]) for k in counts]
        elif name.startswith("simplification"):
            order, _ = simplify.split_order(x, max(counts))
            sets = [np.sort(order[:k]) for k in counts]
        else:
            sets = [baselines.uniform(motion, k).frames - motion.first_frame for k in counts]
        out[name] = [ev.score(rows + motion.first_frame, mode) for rows in sets]
    return out
