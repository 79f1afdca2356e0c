"""Hermite curve fitting with dynamic programming — Önder et al. 2008, "Keyframe reduction
techniques for motion capture data", §3.1 (an offline baseline).

Every channel (rotations unwrapped, degrees; root translation in file units: the curve of
`simplify.curve`) is fitted on its own by cubic Hermite segments between its keyframes. What
this module settles where §3.1 is silent:

- Segment (Önder's matrix form): v(t) = h00(t) p_a + h10(t) L r_a + h01(t) p_b + h11(t) L r_b,
  t = (f - a) / L, L = b - a frames. p_k is the data value at key k (keys are frames of the
  data); r_k is the finite-difference derivative of the data at k (`tangents`: minmod of the
  two one-sided second-order differences, right at segment junctions and at glitches).
  Within a segment, L r is limited to 3 |p_b - p_a| (Fritsch-Carlson's bound), so a key on
  a fast swing (a gimbal swing of the root in 131_04) cannot throw a long segment off (a key
  then has a left and a right tangent). The curve is evaluated directly at the integer
  frames instead of by Bézier subdivision: the subdivision converges to the same cubic, and
  the error is only ever needed at the frames.
- Initial keys (step 1): the first and last frame, and every frame where the first or the
  second derivative of the channel smoothed by a Gaussian of `smooth` frames (default 4,
  33 ms at 120 Hz) changes sign (a zero of the derivative; values within 1e-6 of zero carry
  the previous sign). Unsmoothed mocap derivatives change sign almost every other frame.
  `smooth` is the knob that asks for more keys: less smoothing keeps more sign changes, and
  since the search only moves and drops keys, it sets how close the fit can get.
- Search (steps 2-5): each interior key may move to one of the nine frames key - 4 .. key + 4
  (the endpoints stay), keys stay strictly ordered. Dynamic programming over the keys in
  order finds the combination of minimum cost; for each candidate of key k it keeps the best
  predecessor (Önder's "for each combination of p_i+1, r_i+1 the best p_i, r_i are saved") and
  traces the path back from the last key.
- Cost: the sum of squared errors over the frames (the mean squared error times n) plus
  `key_cost` per key. The paper's cost is the MSE alone, yet it reports far fewer keys than
  frames (8 per channel for 22 frames) without saying how keys disappear. Here the DP may
  also drop an interior key while its two neighbours keep their frames (a transition from key
  k - 2, middle candidate, straight to key k, middle candidate), which it does when the key
  saves less than `key_cost` squared units (degrees^2 x frames); `key_cost=0` is the pure
  MSE search. A larger `key_cost` asks for fewer keys.
- Repeat (step 6): each channel is searched again until a pass lowers its cost by less than
  `tol` (relative; the paper's "predetermined accuracy in the overall cost"; the cost never
  increases: keeping every key in place is one of the DP's choices) or `max_passes`.
- Result: `info["per_channel"]` lists each channel's keys (file numbering),
  `info["mean_keys_per_channel"]` their mean (the paper's Tables 1-2 report this);
  `Keyframes.frames` is the union over channels, score = the number of channels keyed there.
  `reconstruct` rebuilds the channels from the per-channel Hermite segments.

Cost: every pass prices the 81 candidate segments of every key pair (+1 for dropping) in O(1)
each, from running moments of the data over a window per candidate start and a precomputed
Gram matrix of the Hermite basis per segment length; blocks of keys whose neighbourhood did
not move are reused from the previous pass, and a channel leaves the search once it has
converged. The search of a channel (all its passes) is one numba kernel
(`curvefit_kernels`), bit-identical to the numpy form it replaced (tests/curvefit_reference.py):
the pass count grows with the clip (a key sliding 4 frames a pass across a long segment: 16
passes at 10k frames of the bench motion, 53 at 30k and 100k), which numpy paid ~15 calls
per key per pass for. Measured (CPU, loaded shared machine): 100,000 frames of 96 channels
~5 s against 160 s; the same keys.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
from scipy.ndimage import gaussian_filter1d

from ..errors import UsageError
from ..features import Features
from ..keyframes import Keyframes
from ..motion import Motion
from . import curvefit_kernels as _k
from .simplify import curve

__all__ = ["extract", "reconstruct", "hermite", "initial_keys", "tangents", "fit_channels",
           "hermite_curves", "METHOD", "SEARCH", "DEFAULT_SMOOTH", "DEFAULT_KEY_COST",
           "DEFAULT_TOL"]

METHOD = "curvefit"
SEARCH = _k.SEARCH  # nine candidates: key - 4 .. key + 4 (Önder §3.1 step 2)
DEFAULT_SMOOTH = 4.0
DEFAULT_KEY_COST = 1.0
DEFAULT_TOL = 1e-3
_ZERO = 1e-6  # |derivative| below this carries the previous sign
_COLUMNS = 8  # channels per block of full-length numpy work (cache-sized temporaries)


def hermite(t: np.ndarray, pa: np.ndarray, pb: np.ndarray, ra: np.ndarray,
            rb: np.ndarray) -> np.ndarray:
    """Önder's cubic Hermite segment at t in [0, 1] (tangents per unit t)."""
    t2 = t * t
    t3 = t2 * t
    result: np.ndarray = ((2 * t3 - 3 * t2 + 1) * pa + (t3 - 2 * t2 + t) * ra
                          + (-2 * t3 + 3 * t2) * pb + (t3 - t2) * rb)
    return result


def tangents(x: np.ndarray, smooth: float = 0.0) -> np.ndarray:
    """Per-frame derivative of every column of `x` (after a Gaussian of `smooth` frames when
    `smooth` > 0): minmod of the two one-sided second-order differences
    (-3 x_f + 4 x_f+1 - x_f+2) / 2 and (3 x_f - 4 x_f-1 + x_f-2) / 2 (one of them at the ends).

    Each is exact for a quadratic on its side, so they agree where two Hermite segments meet
    with a jump in curvature (the central difference is off by a quarter of the jump there);
    minmod (the smaller one if both have the same sign, else 0) keeps a glitch or a jump from
    giving its neighbours a huge tangent that a Hermite segment would blow up by its length."""
    xs = gaussian_filter1d(x, smooth, axis=0, mode="nearest") if smooth > 0 else x
    n = len(xs)
    if n < 3:
        return np.gradient(xs, axis=0) if n > 1 else np.zeros_like(xs)
    right = np.empty_like(xs)
    left = np.empty_like(xs)
    right[:-2] = (-3 * xs[:-2] + 4 * xs[1:-1] - xs[2:]) / 2
    left[2:] = (3 * xs[2:] - 4 * xs[1:-1] + xs[:-2]) / 2
    right[-2:], left[:2] = left[-2:], right[:2]
    small = np.where(np.abs(left) < np.abs(right), left, right)
    return np.where(left * right > 0, small, 0.0)


def _sign_changes(d: np.ndarray) -> np.ndarray:
    """Mask (n x C) of frames where the sign of `d` differs from the last nonzero sign."""
    s = np.sign(d) * (np.abs(d) > _ZERO)
    idx = np.where(s != 0, np.arange(len(s))[:, None], 0)
    filled = np.take_along_axis(s, np.maximum.accumulate(idx, axis=0), axis=0)
    out = np.zeros(d.shape, dtype=bool)
    out[1:] = (filled[1:] != filled[:-1]) & (filled[:-1] != 0) & (filled[1:] != 0)
    return out


def initial_keys(x: np.ndarray, smooth: float) -> np.ndarray:
    """Önder step 1: mask (n x C) of the first/last frame and the derivative sign changes."""
    d1 = tangents(x, smooth)
    d2 = np.gradient(d1, axis=0) if len(x) > 1 else d1
    mask: np.ndarray = _sign_changes(d1) | _sign_changes(d2)
    mask[[0, -1]] = True
    return mask


_H01 = np.array([0.0, 0.0, 3.0, -2.0])  # Hermite basis, coefficients of t^0..t^3
_H10 = np.array([0.0, 1.0, -2.0, 1.0])
_H11 = np.array([0.0, 0.0, -1.0, 1.0])
_BASIS = (_H01, _H10, _H11)


def _gram(n: int) -> np.ndarray:
    """Entries 00, 11, 22, 01, 02, 12 of G[L] = sum_{j=1}^{L-1} beta(j/L) beta(j/L)^T,
    beta = (h01, h10, h11): (6, n + 1)."""
    j = np.arange(n + 1, dtype=np.float64)
    p = np.arange(7)[:, None]
    power = np.cumsum(j[None, :] ** p, axis=1)  # sum_{i=0}^{J} i^p
    sums = np.zeros((7, n + 1))  # sum_{j=1}^{L-1} (j/L)^p
    sums[:, 2:] = (power[:, 1:-1] - power[:, :1]) / j[2:] ** p
    pairs = ((0, 0), (1, 1), (2, 2), (0, 1), (0, 2), (1, 2))
    return np.stack([np.convolve(_BASIS[r], _BASIS[c]) @ sums for r, c in pairs])


def _block_costs(x: np.ndarray, m: np.ndarray, ch: np.ndarray, a: np.ndarray, ends: np.ndarray,
                 gram: np.ndarray) -> np.ndarray:
    """Segment SSE in channel `ch` (R) of `x` (channels x frames) from each of the 9
    candidates `a` (R x 9) of a key to each of 10 ends (R x 10: the next key's 9 candidates,
    then the key after it, reached from the middle candidate only): R x 9 x 10; +inf where the
    keys would not stay strictly ordered (the search's kernel, row by row)."""
    out = np.empty((len(ch), 9, 10))
    run = np.empty((5, x.shape[1] + 1))
    for r, c in enumerate(ch):
        _k.block_costs(x[c], m[c], np.ascontiguousarray(a[r], dtype=np.int64),
                       np.ascontiguousarray(ends[r], dtype=np.int64), gram, run, out[r])
    return out


def fit_channels(x: np.ndarray, m: np.ndarray, init: list[np.ndarray], key_cost: float,
                 max_passes: int, tol: float = 0.0
                 ) -> tuple[list[np.ndarray], np.ndarray, list[float]]:
    """Önder steps 2-6 on every column of `x`: (keys per channel, cost per channel, total cost
    after each pass). A channel stops when a pass lowers its cost by less than `tol`
    (relative); a lower cost is always kept."""
    n, c_n = x.shape
    keys = [np.asarray(k, dtype=np.int64) for k in init]
    cost = _cost(x, m, keys, key_cost)
    gram = _gram(n)
    work = np.empty(_k.work_size(max((len(k) for k in keys), default=0)))
    run = np.empty((5, n + 1))
    trails = []
    for lo in range(0, c_n, _COLUMNS):  # channels are independent: each runs all its passes
        xt, mt = x[:, lo : lo + _COLUMNS].T.copy(), m[:, lo : lo + _COLUMNS].T.copy()
        for i, c in enumerate(range(lo, lo + len(xt))):
            keys[c], trail = _k.fit_channel(xt[i], mt[i], keys[c], float(cost[c]),
                                            float(key_cost), float(tol), int(max_passes), gram,
                                            work, run)
            trails.append(trail)
    passes = max((len(t) for t in trails), default=min(int(max_passes), 1))
    history = [float(cost.sum())]
    for i in range(passes):
        for c, trail in enumerate(trails):
            if i < len(trail):
                cost[c] = trail[i]
        history.append(float(cost.sum()))
    return keys, cost, history


def _cost(x: np.ndarray, m: np.ndarray, keys: list[np.ndarray], key_cost: float,
          rebuild: Callable[..., np.ndarray] | None = None) -> np.ndarray:
    """SSE of the Hermite fit (`rebuild`: `hermite_curves`) plus key_cost per key, per
    channel (direct evaluation; a block of channels at a time: cache-sized temporaries)."""
    rebuild = rebuild or hermite_curves
    sse = np.empty(x.shape[1])
    for lo in range(0, x.shape[1], _COLUMNS):
        hi = lo + _COLUMNS
        r = x[:, lo:hi] - rebuild(x[:, lo:hi], m[:, lo:hi], keys[lo:hi])
        sse[lo:hi] = np.einsum("ij,ij->j", r, r)
    return sse + key_cost * np.array([len(k) for k in keys])


def hermite_curves(x: np.ndarray, m: np.ndarray, keys: list[np.ndarray]) -> np.ndarray:
    """Every column of `x` rebuilt from its keys by Hermite segments (tangents `m`)."""
    out = x.copy()
    col = np.empty(len(x))
    for c, k in enumerate(keys):
        if len(k) < 2:
            continue
        _k.hermite_fill(np.ascontiguousarray(x[:, c], dtype=np.float64),
                        np.ascontiguousarray(m[:, c], dtype=np.float64),
                        np.ascontiguousarray(k, dtype=np.int64), col)
        out[:, c] = col
    return out


def _check(smooth: float, key_cost: float, max_passes: int, tol: float) -> None:
    if not (np.isfinite(tol) and 0 <= tol < 1):
        raise UsageError(f"curvefit: tol must be in [0, 1), got {tol!r}")
    if not (np.isfinite(smooth) and smooth >= 0):
        raise UsageError(f"curvefit: smooth must be >= 0 frames, got {smooth!r}")
    if not (np.isfinite(key_cost) and key_cost >= 0):
        raise UsageError(f"curvefit: key_cost must be >= 0, got {key_cost!r}")
    if isinstance(max_passes, bool) or int(max_passes) != max_passes or max_passes < 0:
        raise UsageError(f"curvefit: max_passes must be an integer >= 0, got {max_passes!r}")


def _channels(motion: Motion, features: Features | None) -> np.ndarray:
    """`simplify.curve(motion, "channels")`, with the rotations unwrapped once in `features`
    when they are the same bits: unwrapping from frame 0 instead of `first_frame` adds no
    correction when the first captured frame needed none (else the curve unwraps again)."""
    first = motion.first_frame
    if features is not None:
        rot = motion.skeleton.rotation_columns()
        if np.array_equal(features.rotations[first], motion.channels[first, rot]):
            x = motion.channels[first:].copy()
            x[:, rot] = features.rotations[first:]
            return x
    return curve(motion, "channels")


def extract(motion: Motion, *, features: Features | None = None,
            smooth: float = DEFAULT_SMOOTH, key_cost: float = DEFAULT_KEY_COST,
            tol: float = DEFAULT_TOL, max_passes: int = 100) -> Keyframes:
    """Per-channel Hermite keyframes by dynamic programming (Önder §3.1); union as poses.

    Smaller `smooth` or `key_cost` asks for more keys. Frames before `motion.first_frame` are
    skipped; indices are in the file's numbering.
    """
    _check(smooth, key_cost, max_passes, tol)
    first = motion.first_frame
    x = _channels(motion, features)
    n, c_n = x.shape
    params: dict[str, Any] = {"smooth": smooth, "key_cost": key_cost, "tol": tol,
                              "max_passes": max_passes}
    if n < 3:
        rows = np.arange(n)
        return Keyframes(METHOD, rows + first, np.full(n, float(c_n)), params, motion.n_frames,
                         {"per_channel": [(rows + first).tolist()] * c_n})
    m = np.empty_like(x)
    init = []
    for lo in range(0, c_n, _COLUMNS):  # column blocks: the same numbers, cache-sized
        m[:, lo : lo + _COLUMNS] = tangents(x[:, lo : lo + _COLUMNS])
        mask = initial_keys(x[:, lo : lo + _COLUMNS], smooth)
        init += [np.flatnonzero(mask[:, c]) for c in range(mask.shape[1])]
    keys, cost, history = fit_channels(x, m, init, key_cost, int(max_passes), tol)
    counts = np.array([len(k) for k in keys])
    sse = cost - key_cost * counts
    union, hits = np.unique(np.concatenate(keys), return_counts=True)
    info = {
        "per_channel": [(k + first).tolist() for k in keys],
        "channels": motion.skeleton.channel_labels(),
        "keys_per_channel": counts.tolist(),
        "mean_keys_per_channel": float(counts.mean()),
        "initial_keys_per_channel": [len(k) for k in init],
        "mean_initial_keys_per_channel": float(np.mean([len(k) for k in init])),
        "mse_per_channel": (sse / n).tolist(),
        "mse": float(sse.sum() / (n * c_n)),
        "cost_history": history,
        "passes": len(history) - 1,
    }
    return Keyframes(METHOD, union + first, hits.astype(np.float64), params, motion.n_frames,
                     info)


def reconstruct(motion: Motion, result: Keyframes) -> np.ndarray:
    """Channels (n_frames x n_channels) rebuilt from a curvefit result's per-channel keys.

    Rotations come back unwrapped (the curve the fit used); frames before `first_frame` are
    copied.
    """
    if result.method != METHOD or "per_channel" not in result.info:
        raise UsageError("reconstruct needs a curvefit result (per-channel keys in info)")
    first = motion.first_frame
    x = curve(motion, "channels")
    m = tangents(x)
    keys = [np.asarray(k, dtype=np.int64) - first for k in result.info["per_channel"]]
    out = motion.channels.copy()
    out[first:] = hermite_curves(x, m, keys)
    return out
