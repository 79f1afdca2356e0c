"""Pure maths of optimal keys (DESIGN §4.5): segment costs from prefix sums and the dynamic
programme over them. Shared by `streamkey.methods.optimal` (offline and online) and by
`--max-gap`; its module docstring states the definitions settled here. No state, no I/O.

The curve is x (one row per captured frame, D columns); the cost of a segment (a, b) is
Σ_{a<f<b} |x_f − x_a − (f−a)/(b−a) (x_b − x_a)|². With prefix sums of x, f·x and |x|² over a
window this costs O(D) per segment; `chunk_costs` prices every segment ending in a chunk of
frames with two matrix products (never materialising a segment).
"""

from __future__ import annotations

import numpy as np

__all__ = ["CHUNK", "body_rows", "chunk_costs", "band_costs", "pair_costs", "dp_rows",
           "chain", "best_split", "fill_gaps"]

CHUNK = 16  # frames priced together (online: the DP runs when a chunk of frames is complete)


def body_rows(positions: np.ndarray, n_joints: int, height: float,
              weights: np.ndarray | None = None, root_translation: bool = False) -> np.ndarray:
    """Curve rows of FK positions (n, points, 3): the skeleton's joints (ROOT and JOINT, not
    End Sites) minus the root, world orientation — the points of the evaluation's E — divided
    by body height and √joints, so |row difference|² is a frame's mean squared joint error in
    body heights². Optional per-joint `weights` (n_joints,); `root_translation` adds the
    root's own world position as one more weighted point."""
    pts = positions[:, :n_joints]
    rel = pts - pts[:, :1]
    if root_translation:
        rel = np.concatenate([rel, pts[:, :1]], axis=1)
    scale = np.full(rel.shape[1], 1.0 / (height * np.sqrt(n_joints)))
    if weights is not None:
        w = np.asarray(weights, dtype=np.float64)
        scale[: len(w)] *= np.sqrt(w)
    return (rel * scale[None, :, None]).reshape(len(rel), -1)


def _prefix(w: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Exclusive prefix sums of w, u·w (u the local row) and |w|² (first row zero)."""
    n, d = w.shape
    u = np.arange(n, dtype=np.float64)[:, None]
    q0, q1, q2 = np.zeros((n + 1, d)), np.zeros((n + 1, d)), np.zeros(n + 1)
    np.cumsum(w, axis=0, out=q0[1:])
    np.cumsum(u * w, axis=0, out=q1[1:])
    np.cumsum(np.einsum("ij,ij->i", w, w), out=q2[1:])
    return q0, q1, q2


def chunk_costs(x: np.ndarray, b0: int, b1: int, max_len: int) -> np.ndarray:
    """Costs C[i, j] of the segments (a, b), b = b0 + i < b1, a = b − max_len + j (j < max_len);
    inf where a < 0. Reads rows max(0, b0 − max_len) .. b1 − 1 of `x` only.

    A pure function of those rows, so offline and online (chunks aligned to the same stream
    indices) get bit-identical costs.
    """
    s = max(0, b0 - max_len)
    w = x[s:b1]
    w = w - w.mean(axis=0)  # costs are shift invariant; smaller sums round less
    q0, q1, q2 = _prefix(w)
    nb = b1 - b0
    ub = np.arange(b0 - s, b1 - s)  # local rows of the segment ends
    pb = w[ub]
    ua_all = np.arange(len(w))
    # a-only terms (local rows ua, prefixes up to ua + 1)
    r = q1[ua_all + 1] - ua_all[:, None] * q0[ua_all + 1]
    na = np.einsum("ij,ij->i", w, w)
    h1 = np.einsum("ij,ij->i", w, q0[ua_all + 1])
    h3 = np.einsum("ij,ij->i", w, q1[ua_all + 1])
    # cross terms: x_a.x_b, x_a.Q0[b], x_a.Q1[b] and R_a.x_b (two matrix products)
    g = w @ np.concatenate([pb, q0[ub], q1[ub]]).T
    x1, x2, x3 = g[:, :nb], g[:, nb : 2 * nb], g[:, 2 * nb :]
    x4 = r @ pb.T
    # the band a = b - max_len + j
    ua = ub[:, None] - max_len + np.arange(max_len)[None, :]
    valid = ua >= 0
    ua = np.where(valid, ua, 0)
    col = np.arange(nb)[:, None]
    m = np.maximum(ub[:, None] - ua, 1).astype(np.float64)
    x1, x2, x3, x4 = x1[ua, col], x2[ua, col], x3[ua, col], x4[ua, col]
    na_a, nb_b = na[ua], na[ub][:, None]
    g0 = np.einsum("ij,ij->i", pb, q0[ub])[:, None]
    g1 = np.einsum("ij,ij->i", pb, q1[ub])[:, None]
    a2 = q2[ub][:, None] - q2[ua + 1]
    s1 = (m - 1.0) / 2.0
    s2 = (m - 1.0) * (2.0 * m - 1.0) / (6.0 * m)
    uaf = ua.astype(np.float64)
    dt = (g1 - uaf * g0 - x4) - (x3 - h3[ua] - uaf * x2 + uaf * h1[ua])
    cost = (a2 + (m - 1.0) * na_a + s2 * (nb_b - 2.0 * x1 + na_a) - 2.0 * (x2 - h1[ua])
            - 2.0 * dt / m + 2.0 * s1 * (x1 - na_a))
    cost = np.maximum(cost, 0.0)
    cost[m <= 1.0] = 0.0
    cost[~valid] = np.inf
    return cost


def band_costs(x: np.ndarray, max_len: int, chunk: int = CHUNK) -> np.ndarray:
    """`chunk_costs` of every frame (n, max_len), chunks aligned at multiples of `chunk`."""
    n = len(x)
    out = np.empty((n, max_len))
    for b0 in range(0, n, chunk):
        b1 = min(n, b0 + chunk)
        out[b0:b1] = chunk_costs(x, b0, b1, max_len)
    return out


def pair_costs(x: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Costs of arbitrary segments (a[i], b[i]) of `x` (a < b), O(D) each from prefix sums."""
    a = np.asarray(a, dtype=np.int64)
    b = np.asarray(b, dtype=np.int64)
    if len(a) == 0:
        return np.zeros(0)
    s, e = int(a.min()), int(b.max()) + 1
    w = x[s:e] - x[s:e].mean(axis=0)
    q0, q1, q2 = _prefix(w)
    ua, ub = a - s, b - s
    m = (ub - ua).astype(np.float64)
    pa, pb = w[ua], w[ub]
    d = pb - pa
    a0 = q0[ub] - q0[ua + 1]
    a1 = q1[ub] - q1[ua + 1]
    t = (a1 - ua[:, None] * a0) / m[:, None]

    def dot(p: np.ndarray, q: np.ndarray) -> np.ndarray:
        return np.einsum("ij,ij->i", p, q)

    s1 = (m - 1.0) / 2.0
    s2 = (m - 1.0) * (2.0 * m - 1.0) / (6.0 * m)
    cost = (q2[ub] - q2[ua + 1] + (m - 1.0) * dot(pa, pa) + s2 * dot(d, d)
            - 2.0 * dot(pa, a0) - 2.0 * dot(d, t) + 2.0 * s1 * dot(pa, d))
    return np.where(m <= 1.0, 0.0, np.maximum(cost, 0.0))


def dp_rows(costs: np.ndarray, f: np.ndarray, bp: np.ndarray, keys: np.ndarray, b0: int,
            b1: int, lam: float, floor: int = 0, tolerance: float | None = None,
            c0: int = 0) -> None:
    """Advance the DP over frames b0 .. b1 − 1 in place (`f`, `bp`, `keys` indexed by frame,
    `costs[b − c0]` is frame b's band).

    Penalised form: F(b) = min_a F(a) + cost(a, b) + λ over floor ≤ a < b, b − a ≤ L, ties to
    the earliest a. Tolerance form (`tolerance` given): among a with cost(a, b) ≤ tolerance ·
    (b − a), fewest keys, then least F (summed cost). `keys[b]` counts the chain's keys.
    """
    max_len = costs.shape[1]
    for b in range(b0, b1):
        lo = max(b - max_len, floor)
        c = costs[b - c0, max_len - (b - lo):]
        vals = f[lo:b] + c
        if tolerance is None:
            i = int(np.argmin(vals))
            f[b] = vals[i] + lam
        else:
            ok = c <= tolerance * np.arange(b - lo, 0, -1)
            ok &= np.isfinite(vals)
            if not ok.any():
                f[b], bp[b], keys[b] = np.inf, -1, 0
                continue
            k = np.where(ok, keys[lo:b], np.iinfo(np.int64).max)
            best = np.flatnonzero(k == k.min())
            i = int(best[np.argmin(vals[best])])
            f[b] = vals[i]
        bp[b] = lo + i
        keys[b] = keys[lo + i] + 1


def chain(bp: np.ndarray, end: int, stop: int = -1) -> list[int]:
    """Frames of the back-pointer chain from `end` down to (excluding) frames ≤ `stop`,
    increasing."""
    out = []
    k = end
    while k > stop:
        out.append(int(k))
        k = int(bp[k])
    return out[::-1]


def best_split(x: np.ndarray, a: int, e: int, last: int) -> int:
    """Frame k in (a, last] minimising cost(a, k) + cost(k, e) (ties: earliest)."""
    ks = np.arange(a + 1, last + 1)
    total = pair_costs(x, np.full(len(ks), a), ks) + pair_costs(x, ks, np.full(len(ks), e))
    return int(ks[int(np.argmin(total))])


def fill_gaps(x: np.ndarray, keys: np.ndarray, max_gap: int) -> np.ndarray:
    """Keys (rows, sorted) with a key inserted wherever consecutive keys lie more than
    `max_gap` frames apart: left to right, at the best frame k of (a, a + max_gap] by
    cost(a, k) + cost(k, a + max_gap + 1)."""
    keys = [int(k) for k in np.asarray(keys, dtype=np.int64)]
    out: list[int] = []
    for i, a in enumerate(keys):
        out.append(a)
        if i + 1 == len(keys):
            break
        b = keys[i + 1]
        while b - a > max_gap:
            a = best_split(x, a, a + max_gap + 1, a + max_gap)
            out.append(a)
    return np.array(out, dtype=np.int64)
