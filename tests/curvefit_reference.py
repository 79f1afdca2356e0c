"""The numpy form of curvefit's search (Önder steps 2-6) as it was before the numba
kernels (`streamkey.methods.curvefit_kernels`): kept here, verbatim, as the reference the
kernels must reproduce bit for bit (tests/test_curvefit.py)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from streamkey.methods.curvefit import SEARCH, _gram, hermite
from streamkey.methods.curvefit import _cost as kernel_cost

_BATCH_KEYS = 20_000  # keys per DP batch of channels (bounds the 9 x 18 cost blocks held)
_CHUNK = 300_000  # moment-window cells per numpy batch (cache-friendly size)


def _limit(ra: np.ndarray, rb: np.ndarray, delta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Segment tangents (per unit t) limited to 3 |x_b - x_a| (Fritsch-Carlson's bound): a
    steep key next to a flat one would otherwise swing the cubic far outside the data."""
    bound = 3 * np.abs(delta)
    return np.clip(ra, -bound, bound), np.clip(rb, -bound, bound)


def hermite_curves(x: np.ndarray, m: np.ndarray, keys: list[np.ndarray]) -> np.ndarray:
    """Every column of `x` rebuilt from its keys by Hermite segments (tangents `m`)."""
    out = x.copy()
    n = len(x)
    frames = np.arange(n)
    for c, k in enumerate(keys):
        if len(k) < 2:
            continue
        seg = np.clip(np.searchsorted(k, frames, side="right") - 1, 0, len(k) - 2)
        a, b = k[seg], k[seg + 1]
        length = (b - a).astype(np.float64)
        t = (frames - a) / length
        ra, rb = _limit(m[a, c] * length, m[b, c] * length, x[b, c] - x[a, c])
        out[:, c] = hermite(t, x[a, c], x[b, c], ra, rb)
        out[k, c] = x[k, c]
    return out


def _cost(x: np.ndarray, m: np.ndarray, keys: list[np.ndarray], key_cost: float) -> np.ndarray:
    """SSE of the Hermite fit (the numpy rebuild above) plus key_cost per key, per channel."""
    return kernel_cost(x, m, keys, key_cost, hermite_curves)


@dataclass
class _Problem:
    """A batch of channels: data and tangents (C x n), padded key positions (C x K)."""

    x: np.ndarray
    m: np.ndarray
    keys: np.ndarray  # padded with n - 1
    count: np.ndarray  # real keys per channel


def _candidates(p: _Problem) -> np.ndarray:
    """C x K x 9 candidate frames; the endpoints and the padding stay put."""
    n = p.x.shape[1]
    cand = np.clip(p.keys[:, :, None] + np.arange(-SEARCH, SEARCH + 1), 0, n - 1)
    k = np.arange(p.keys.shape[1])[None, :]
    fixed = (k == 0) | (k >= p.count[:, None] - 1)
    return np.where(fixed[:, :, None], p.keys[:, :, None], cand)


def _window(x: np.ndarray, ch: np.ndarray, o: np.ndarray, width: int
            ) -> tuple[np.ndarray, np.ndarray]:
    """v_i = x[ch, o + i] - x[ch, o], i = 0..width, and the running sums over i of v_i i^q
    (q = 0..3) and v_i^2: (rows, width + 1), (5, rows, width + 1). Local offsets keep the sums
    exact enough."""
    i = np.arange(width + 1)
    v = x[ch[:, None], np.minimum(o[:, None] + i, x.shape[1] - 1)] - x[ch, o][:, None]
    fi = i.astype(np.float64)
    out = np.empty((5, len(o), width + 1))
    out[0] = v
    np.multiply(v, fi, out=out[1])
    np.multiply(out[1], fi, out=out[2])
    np.multiply(out[2], fi, out=out[3])
    np.multiply(v, v, out=out[4])
    return v, np.cumsum(out, axis=2, out=out)


def _moments(v: np.ndarray, run: np.ndarray, d: np.ndarray, inner: np.ndarray) -> np.ndarray:
    """Sums over j = 1..J (J = `inner`) of u_j j^q (q = 0..3) and u_j^2 with u_j = v_(d+j) - v_d,
    for segments starting d frames into the window (d, J: rows x entries): (5, rows, entries).

    Re-centred from the window's running sums: (i - d)^q expanded binomially (d <= 8)."""
    rows, width = v.shape
    base = (np.arange(rows) * width)[:, None]
    lo, hi = (base + d).ravel(), (base + d + inner).ravel()
    flat = run.reshape(5, -1)
    a = (flat[:, hi] - flat[:, lo]).reshape(5, rows, -1)
    vd = v.reshape(-1)[lo].reshape(rows, -1)
    fd, fj = d.astype(np.float64), inner.astype(np.float64)
    p1 = fj * (fj + 1) / 2
    out = np.empty_like(a)
    out[0] = a[0] - vd * fj
    out[1] = a[1] - fd * a[0] - vd * p1
    out[2] = a[2] - 2 * fd * a[1] + fd**2 * a[0] - vd * (p1 * (2 * fj + 1) / 3)
    out[3] = a[3] - 3 * fd * a[2] + 3 * fd**2 * a[1] - fd**3 * a[0] - vd * p1**2
    out[4] = a[4] - 2 * vd * a[0] + fj * vd**2
    return out


def _sse(mom: np.ndarray, delta: np.ndarray, ra: np.ndarray, rb: np.ndarray,
         length: np.ndarray, gram: np.ndarray) -> np.ndarray:
    """SSE of Hermite segments over their interior frames, from their moments (`mom`:
    (..., 5)): sum u^2 - 2 gamma . sum(u beta) + gamma^T G gamma, gamma = (x_b - x_a, L r_a,
    L r_b), beta = (h01, h10, h11)."""
    lf = length.astype(np.float64)
    a1 = mom[1] / lf
    a2 = mom[2] / lf**2
    a3 = mom[3] / lf**3
    g = gram[:, length]
    cross = delta * (3 * a2 - 2 * a3) + ra * (a1 - 2 * a2 + a3) + rb * (a3 - a2)
    quad = (g[0] * delta**2 + g[1] * ra**2 + g[2] * rb**2
            + 2 * (g[3] * delta * ra + g[4] * delta * rb + g[5] * ra * rb))
    return np.maximum(mom[4] - 2 * cross + quad, 0.0)


def _block_costs(x: np.ndarray, m: np.ndarray, ch: np.ndarray, a: np.ndarray, ends: np.ndarray,
                 gram: np.ndarray) -> np.ndarray:
    """Segment SSE in channel `ch` (R) of `x` (channels x frames) from each of the 9
    candidates `a` (R x 9) of a key to each of 10 ends (R x 10: the next key's 9 candidates,
    then the current frame of the key after it, reached from the middle candidate only):
    R x 9 x 10; +inf where the keys would not stay strictly ordered. One window of running
    sums per key serves its nine candidate starts."""
    n_rows = len(ch)
    o = a[:, 0]
    end = np.repeat(ends[:, None, :], 9, axis=1)
    far = np.arange(9) != SEARCH
    end[:, far, 9] = a[:, far]  # the skip over a key starts from the middle candidate only
    length = (end - a[:, :, None]).reshape(n_rows, 90)
    cost = np.where(length == 1, 0.0, np.inf)
    ok = length >= 2
    width = np.where(ok, end.reshape(n_rows, 90) - 1 - o[:, None], 0).max(axis=1)
    start = np.repeat(a - o[:, None], 10, axis=1)  # d of every entry, R x 90
    group = np.ceil(np.log2(np.maximum(width, 1))).astype(np.int64)
    for g in np.unique(group[width > 0]):
        rows = np.flatnonzero((group == g) & (width > 0))
        step = max(1, min(_CHUNK // (5 * 2 ** int(g)), 200))
        for lo in range(0, len(rows), step):
            r = rows[lo : lo + step]
            c, ln, okr = ch[r], length[r], ok[r]
            w = int(width[r].max())
            v, run = _window(x, c, o[r], w)
            inner = np.where(okr, ln - 1, 0)
            mom = _moments(v, run, np.where(okr, start[r], 0), inner)
            lp = np.maximum(ln, 2)
            aa = np.repeat(a[r], 10, axis=1)
            bb = np.where(okr, end[r].reshape(len(r), 90), aa)
            xa, ma = x[c[:, None], aa], m[c[:, None], aa]
            delta = x[c[:, None], bb] - xa
            ra, rb = _limit(ma * lp, m[c[:, None], bb] * lp, delta)
            cost[r] = np.where(okr, _sse(mom, delta, ra, rb, lp, gram), cost[r])
    return cost.reshape(n_rows, 9, 10)


class _Cache:
    """Segment-cost blocks of the last pass, keyed by (channel, key, next two keys): a key
    whose neighbourhood did not move reuses its 9 x 10 block."""

    def __init__(self) -> None:
        self.codes = np.zeros(0, dtype=np.int64)
        self.blocks = np.zeros((0, 9, 10))
        self._new: list[tuple[np.ndarray, np.ndarray]] = []

    def costs(self, x: np.ndarray, m: np.ndarray, codes: np.ndarray, ch: np.ndarray,
              a: np.ndarray, ends: np.ndarray, gram: np.ndarray) -> np.ndarray:
        """Blocks for `codes` (flat), computing only those not seen in the last pass."""
        idx = np.minimum(np.searchsorted(self.codes, codes), max(len(self.codes) - 1, 0))
        hit = (self.codes[idx] == codes) if len(self.codes) else np.zeros(len(codes), bool)
        out = np.empty((len(codes), 9, 10))
        out[hit] = self.blocks[idx[hit]]
        miss = ~hit
        out[miss] = _block_costs(x, m, ch[miss], a[miss], ends[miss], gram)
        self._new.append((codes, out))
        return out

    def end_pass(self) -> None:
        """Keep only the blocks used in this pass."""
        if not self._new:
            self.codes, self.blocks = np.zeros(0, dtype=np.int64), np.zeros((0, 9, 10))
            return
        codes = np.concatenate([c for c, _ in self._new])
        blocks = np.concatenate([b for _, b in self._new])
        self.codes, first = np.unique(codes, return_index=True)
        self.blocks = blocks[first]
        self._new = []


def _dp(p: _Problem, key_cost: float, gram: np.ndarray, cache: _Cache,
        channels: np.ndarray) -> tuple[list[np.ndarray], np.ndarray]:
    """One search pass (Önder steps 2-5) over a batch: (keys per channel, cost per channel).

    `channels` are the batch's column numbers (cache keys)."""
    n = p.x.shape[1]
    cand = _candidates(p)
    c_n, k_n, _ = cand.shape
    kp = np.concatenate([p.keys, np.full((c_n, 2), n - 1)], axis=1)
    nxt = np.concatenate([cand[:, 1:], np.full((c_n, 1, 9), n - 1)], axis=1)
    ends = np.concatenate([nxt, kp[:, 2:, None]], axis=2)  # C x K x 10
    codes = ((channels[:, None] * n + kp[:, :-2]) * n + kp[:, 1:-1]) * n + kp[:, 2:]
    real = np.arange(k_n)[None, :] < p.count[:, None]  # padding rows are never read
    ch = np.broadcast_to(np.arange(c_n)[:, None], (c_n, k_n))
    block = np.full((c_n, k_n, 9, 10), np.inf)
    block[real] = cache.costs(p.x, p.m, codes[real], ch[real], cand[real], ends[real], gram)
    c1, c2 = block[:, :-1, :, :9], block[:, :-2, SEARCH, 9]
    value = np.full((c_n, k_n, 9), np.inf)
    value[:, 0] = key_cost  # the first key
    back = np.zeros((c_n, k_n, 9, 2), dtype=np.int64)  # (keys back, candidate)
    for k in range(1, k_n):
        live = (k < p.count)[:, None]
        t1 = value[:, k - 1, :, None] + c1[:, k - 1]
        best, arg, step = t1.min(axis=1), t1.argmin(axis=1), np.ones((c_n, 9), np.int64)
        if k >= 2:  # or drop key k - 1 (interior) while keys k - 2 and k keep their frames
            b2 = value[:, k - 2, SEARCH] + c2[:, k - 2]
            better = (b2 < best[:, SEARCH]) & (k - 1 < p.count - 1)
            best[better, SEARCH] = b2[better]
            arg[better, SEARCH] = SEARCH
            step[better, SEARCH] = 2
        value[:, k] = np.where(live, best + key_cost, value[:, k - 1])
        back[:, k, :, 0] = np.where(live, step, 0)
        back[:, k, :, 1] = arg
    cost = value[np.arange(c_n), p.count - 1, SEARCH]
    return _trace(cand, back, p.count - 1, n), cost


def _trace(cand: np.ndarray, back: np.ndarray, last: np.ndarray, n: int) -> list[np.ndarray]:
    """Follow the saved predecessors back from every channel's last key: sorted key frames
    per channel (O(keys), whatever the clip length)."""
    c_n = len(last)
    rows = np.arange(c_n)
    k, j = last.copy(), np.full(c_n, SEARCH)
    hit_rows, hit_frames = [rows], [cand[rows, k, j]]
    while np.any(k > 0):
        on = k > 0
        r, kk, jj = rows[on], k[on], j[on]
        k[on], j[on] = kk - back[r, kk, jj, 0], back[r, kk, jj, 1]
        hit_rows.append(r)
        hit_frames.append(cand[r, k[on], j[on]])
    r_all, f_all = np.concatenate(hit_rows), np.concatenate(hit_frames)
    order = np.lexsort((f_all, r_all))
    r_all, f_all = r_all[order], f_all[order]
    keep = np.ones(len(r_all), dtype=bool)
    keep[1:] = (r_all[1:] != r_all[:-1]) | (f_all[1:] != f_all[:-1])
    r_all, f_all = r_all[keep], f_all[keep]
    return np.split(f_all.astype(np.int64), np.searchsorted(r_all, np.arange(1, c_n)))


def _pad(key_lists: list[np.ndarray], n: int) -> tuple[np.ndarray, np.ndarray]:
    count = np.array([len(k) for k in key_lists], dtype=np.int64)
    keys = np.full((len(key_lists), int(count.max())), n - 1, dtype=np.int64)
    for c, k in enumerate(key_lists):
        keys[c, : len(k)] = k
    return keys, count


def _batches(channels: np.ndarray, counts: np.ndarray) -> list[np.ndarray]:
    """Channels grouped by key count (less padding), about _BATCH_KEYS keys per batch."""
    order = channels[np.argsort(counts[channels], kind="stable")]
    out, cur, size = [], [], 0
    for c in order:
        if cur and (len(cur) + 1) * int(counts[c]) > _BATCH_KEYS:
            out.append(np.array(cur))
            cur, size = [], 0
        cur.append(c)
        size += int(counts[c])
    if cur:
        out.append(np.array(cur))
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
    history = [float(cost.sum())]
    gram = _gram(n)
    cache = _Cache()
    xt, mt = np.ascontiguousarray(x.T), np.ascontiguousarray(m.T)
    active = np.arange(c_n)
    for _ in range(max_passes):
        counts = np.array([len(k) for k in keys])
        still = []
        for batch in _batches(active, counts):
            padded, count = _pad([keys[c] for c in batch], n)
            found, new = _dp(_Problem(xt[batch], mt[batch], padded, count), key_cost, gram,
                            cache, batch)
            for i, c in enumerate(batch):
                if new[i] < cost[c] * (1 - 1e-12):
                    if new[i] < cost[c] * (1 - tol):
                        still.append(c)
                    keys[c], cost[c] = found[i], new[i]
        cache.end_pass()
        history.append(float(cost.sum()))
        active = np.array(sorted(still), dtype=np.int64)
        if len(active) == 0:
            break
    return keys, cost, history
