"""Multiscale motion saliency — C. Halit, "A multi scale motion saliency method for keyframe
extraction from motion capture sequences", MSc thesis, Bilkent University, 2010, chapter 3
(journal version: Halit & Capin, Computer Animation and Virtual Worlds, 2011).

Offline: `extract(motion)`. Definitions this module settles (where they differ from the thesis):

- Input (thesis eq. 3.1): the unwrapped rotation channels of the captured frames (root
  position excluded), unwrapped from the first captured frame (as a stream starting there is).
  Every column is standardised over the clip; columns with variance <= 1e-10 deg^2 are dropped.
  Moments are taken after subtracting the first captured frame (less cancellation).
- PCA (eq. 3.2-3.3): eigen-decomposition of the correlation matrix (the covariance of the
  standardised columns, population normalisation), components by decreasing eigenvalue, each
  eigenvector signed so that its largest-magnitude entry is positive. k components; with
  `variance_rule` k = max(k, smallest k reaching 90 % of the variance) (thesis Fig. 3.2).
- Contact (sec. 3.3): the last two of the k curves are replaced by the left and right ankle height
  divided by body height (unit-free), analysed with sigma = `FOOT_SIGMA` (1/40 s, 3 frames
  at 120 Hz). They take the eigenvalues of
  the two components they replace as cluster weights, so the weights still sum to the
  variance of k components.
- Curvature (eq. 3.4 with D' in the denominator): D' is the central difference
  (one-sided at the two ends), D'' the second difference D(f+1) - 2 D(f) + D(f-1), copied from
  the neighbour at the two ends, both per 1/120 s (`REFERENCE_FPS`): divided by h and h^2,
  h = 120 / fps, so that a take at another rate has the curvature of the same motion and
  120 Hz the per-frame values. C = |D''| / (1 + D'^2)^(3/2).
- Gaussian mean (eq. 3.5): G(f, s) = sum of w(x - f) C(x) / sum of w(x - f) over the frames x of
  the clip with |x - f| <= floor(2 s), w(d) = exp(-d^2 / (2 s^2)). Near the clip's ends the
  weights are renormalised over the part of the window inside the clip.
- Scales (eq. 3.6-3.7): S_i = |G(f, s_i) - G(f, 2 s_i)|, s_i = sigma * (1, 1.5, 2, 2.5).
- Units: sigma is a duration (`streamkey.units.Duration`; a plain number is frames), used in
  frames of the take (not rounded; kernels sampled at its frames). Windows, the cluster
  length 2 sigma and the online lookahead, history and `update_every` follow the rate.
- Normalisation (Itti): per curve, H = the largest raw value over its four maps; map i has
  global maximum M_i and m_i = mean of its local maxima (interior frames, v[f-1] < v[f] >=
  v[f+1]) with one occurrence of M_i left out (0 if none is left). Map i rescaled to [0, H]
  and multiplied by (H - m_i H / M_i)^2, i.e. S_i * H^3 / M_i * (1 - m_i / M_i)^2; S = sum.
  Every statistic is a sum, a count or a maximum, so a running version is exact at the end.
- Candidates (sec. 3.1.3): frames with S_j(f) > mean of S_j over the clip, per curve j.
- Clusters (sec. 3.1.4): runs of consecutive frames that are a candidate on any curve, cut into
  pieces of 2 sigma frames counted from the run's start (for a fractional 2 sigma, a cut
  wherever the run's candidate count crosses a multiple of it, `saliency_math.cuts`).
  Weighted mean frame with one entry per (frame, curve) candidate, weight = the curve's
  eigenvalue; the keyframe is the cluster frame nearest to it (ties within 1e-9 go to the
  earlier frame). A cluster with a foot candidate picks among its foot-candidate frames (sec. 3.3).
- Score: the cluster's saliency, sum over its (frame, curve) candidates of
  weight_j * S_j(f) / mean(S_j), divided by the sum of all k weights.
- Presets (thesis sec. 4.2): "low" sigma = 1/12 s (10 frames at 120 Hz), k = 7; "high"
  sigma = 1/40 s (3 frames), k = 10 (at least half a frame at any rate); "auto" picks "high"
  when the mean speed of Miura's 16 body parts in the pelvis frame is at least
  `AUTO_SPEED_THRESHOLD` body heights per second (runs, brisk walks, fast dance in the shared
  data), else "low". The speed is the mean over the moving frame steps (mean part speed
  above `STILL_SPEED`) of the first `AUTO_SECONDS` (2 s) from the first moving step on: a
  calibration hold before the take, or stillness after a take shorter than 2 s, counts for
  nothing. The first 2 s make the rule causal, so the online keyframer
  (`saliency_auto.AutoOnline`) takes the same decision; on all 35 shared clips it equals
  the whole-clip rule. `sigma` and `k` override the preset's values.

Online: `Online(skeleton, fps, sigma=..., lookahead=...)`. Each global statistic of the
offline method becomes a running one, chosen so that at `flush()` it equals the global one
exactly (sums, counts and maxima, with the same batch arithmetic as offline), which is what
makes the online result equal the offline one when every decision waits for `flush()`:

- Standardisation and PCA basis -> running moments (count, sum of x, sum of x x^T after
  subtracting the stream's first frame): frames that leave the window are folded into a total,
  the window is added in one batch when the basis is recomputed. Recomputed rarely (warm-up
  end at frame `lookahead`, whenever the frame count doubles, at least every `update_every`
  frames, and at `flush()`), because each basis change moves every curve (the main source of
  disagreement with offline) and costs a batch recompute of the window. New components are
  matched to the previous ones (greedy on |cos|, signs aligned) so that curve j stays curve j
  and keeps its running statistics. Frames that left the window are folded in pieces of
  `FOLD_EVERY` (64) frames. Only the first basis is computed in a push (frame `lookahead`,
  from the frames so far, ~1.5 ms once per window: computed a frame earlier in `idle()`, it
  measured 0.928 / min 0.802 at lookahead 240 instead of 0.931 / 0.811). Every later update,
  once frame 2 radius + 2 has arrived (the stream-start rows' support), is spread: due at
  frame u, it takes the moments of the window at u, and its work (moments, correlation,
  eigen-decomposition, matching, curves, curvatures, blocks of maps, the switch: one piece a
  frame, in `idle()`) runs over the next `SPREAD` (24) frames; the new basis decides from
  frame u + 24 on, the frames in between are classified with the previous one (at once,
  the stream-start updates cost 1.5-6.5 ms in a deciding push). Measured on the shared clips
  (sigma = 10), mean F1 against offline (lowest clip): 0.801 (0.500) at lookahead 30, 0.852
  (0.615) at 60, 0.895 (0.773) at 121, 0.931 (0.811) at 240; with the stream-start updates
  made at once 0.804, 0.851, 0.897 (0.773), 0.932 (0.822). Other timings of the same work
  move these by +-0.005.
- Itti maxima M_i and H, mean of the other local maxima, and the mean-saliency threshold ->
  per (curve, scale) running count, sum, maximum, and local-maximum count / sum / maximum of
  the raw maps of every frame so far. Whole-history statistics, not a short window (they
  agree better). The frames of the window (the lookahead, and at least the last
  `HISTORY_SECONDS` = 10 s) are recomputed with each new basis; older ones keep the values of
  the basis they were computed with. Measured on the shared clips at sigma = 10 and the
  default lookahead: mean F1 against offline 0.877 with the lookahead-sized window only,
  0.894 with 10 s, 0.895 keeping the whole stream.
- Clustering needs no global statistic: runs and 2 sigma cuts are decided frame by frame.
- Below the support (lookahead < radius + 1 + 2 sigma): a frame whose deadline comes
  before its Gaussian windows are complete is classified from maps whose windows are cut at
  the newest frame t, weights renormalised over the part inside, with the curvature of t by
  the clip-end rule (D' one-sided, D'' copied): the offline edge rule, as if the clip ended at
  t. These provisional maps are used once and never enter the running statistics, which keep
  the final maps only. While the final maps cover fewer frames than the last basis update saw
  (stream start, at most `radius` final rows at that update), the Itti statistics come from
  the maps of that update (cut at its frame) instead. A cluster still open at its deadline is
  closed there; the run goes on in a new cluster on the same 2 sigma grid. Measured on the
  shared clips at sigma = 10 (results/agreement_saliency_lookahead.md): mean F1 0.804 at 30
  frames, 0.851 at 60, 0.897 at 121 (the default).
"""

from __future__ import annotations

import copy
from collections import deque
from dataclasses import dataclass
from typing import Any, cast

import numpy as np

from ..errors import UsageError
from ..features import DEFAULT_NOISE_CUTOFF_HZ, Features, compute_features
from ..keyframes import KeyframeEvent, Keyframes
from ..motion import Motion, Skeleton
from ..online import DEFAULT_MAX_BRIDGE_FRAMES, FeatureBlock, OnlineKeyframer
from ..roles import MIURA_ROLES
from ..units import Duration, DurationLike, whole_frames
from .saliency_math import (
    FOOT_SIGMA,
    REFERENCE_FPS,
    SCALES,
    Basis,
    Clusterer,
    MapStats,
    Moments,
    classify_block,
    cluster_keyframes,
    cluster_length,
    cluster_size,
    combine,
    components,
    correlation,
    curvature,
    curve_weights,
    curves_of,
    end_curvature,
    fit_k,
    frames_at,
    gaussian_means,
    itti_factors,
    kernel,
    kernel_bank,
    local_max_mask,
    map_stats,
    maps_of,
    match_basis,
    moments,
    normalisation,
    pca_basis,
    pick_keyframe,
    remap,
    remap_stats,
    ring_curves,
    ring_maps_of,
    scale_maps,
    support_radius,
    time_step,
    truncated_maps,
    widths,
)

TRACE_FRAMES = 2400  # 20 s at 120 Hz of per-frame saliency kept for live views
CANDIDATE_EVERY = 4  # frames between two derivations of the provisional candidates
SPREAD = 24  # frames over which a periodic basis update is computed before it applies
_NO_STOP = 1 << 62  # `classify_block` without a deadline
FOLD_EVERY = 64  # frames that left the window folded into the totals at once

__all__ = ["extract", "Online", "METHOD", "PRESETS", "AUTO_SPEED_THRESHOLD", "FOOT_SIGMA",
           "SCALES", "HISTORY_SECONDS", "Basis", "Moments", "MapStats", "moments", "pca_basis",
           "curvature", "kernel", "widths", "kernel_bank", "gaussian_means", "scale_maps",
           "local_max_mask", "map_stats", "normalisation", "combine", "curves_of", "maps_of",
           "curve_weights", "cluster_keyframes", "pick_keyframe", "match_basis",
           "choose_preset", "resolve_params", "cluster_size", "cluster_length", "support_radius",
           "auto_preset", "auto_frames", "AUTO_SECONDS", "STILL_SPEED", "step_speeds",
           "moving", "REFERENCE_FPS", "UPDATE_EVERY", "preset_sigma", "time_step"]

METHOD = "saliency"
# sigma in frames of 120 Hz (`REFERENCE_FPS`): 1/12 s and 1/40 s of motion at any rate
PRESETS: dict[str, tuple[float, int]] = {"low": (10.0, 7), "high": (3.0, 10)}
UPDATE_EVERY = Duration.seconds(10.0)  # online: the basis is recomputed at least this often
AUTO_SPEED_THRESHOLD = 0.85  # body heights per second
AUTO_SECONDS = 2.0  # "auto" decides on the first 2 s of motion (offline and online alike)
STILL_SPEED = 0.005  # body heights per second: slower steps are not motion for "auto"
HISTORY_SECONDS = 10.0  # online: past kept for recomputation when the basis changes


# --------------------------------------------------------------------------- parameters

def auto_frames(fps: float) -> int:
    """Frames the "auto" rule looks at: the first `AUTO_SECONDS` from the first moving step
    (`moving`) on."""
    return max(2, int(round(AUTO_SECONDS * float(fps))))


def step_speeds(p: np.ndarray) -> np.ndarray:
    """Per frame step and body part, the distance moved (body heights) between consecutive
    rows of Miura-role positions `p` (n, parts, 3): (n - 1, parts)."""
    steps: np.ndarray = np.linalg.norm(np.diff(p, axis=0), axis=2)
    return steps


def moving(steps: np.ndarray, fps: float) -> np.ndarray:
    """Which steps of `step_speeds` move: mean part speed above `STILL_SPEED` (a calibration
    hold or a frozen source does not; captured motion, even standing, does)."""
    moves: np.ndarray = steps.mean(axis=1) * fps > STILL_SPEED
    return moves


def auto_preset(steps: np.ndarray, fps: float) -> tuple[str, float]:
    """The "auto" rule on the moving steps of its window (rows of `step_speeds`):
    ("high" | "low", mean speed in body heights/s)."""
    if len(steps) == 0:
        return "low", 0.0
    speed = float(steps.mean() * fps)
    return ("high" if speed >= AUTO_SPEED_THRESHOLD else "low"), speed


def choose_preset(features: Features, first: int) -> tuple[str, float]:
    """The "auto" rule: ("high" | "low", mean speed in body heights per second) over the
    moving steps of the first `AUTO_SECONDS` from the first moving step on (a calibration
    hold or stillness counts for nothing), as the online keyframer decides it (causal)."""
    fps = features.motion.fps
    p = features.role_positions(MIURA_ROLES)[first:] / features.body_height
    steps = step_speeds(p)
    mv = moving(steps, fps)
    if not mv.any():
        return auto_preset(steps[:0], fps)
    start = int(np.argmax(mv))
    window = mv[start : start + auto_frames(fps) - 1]
    return auto_preset(steps[np.flatnonzero(window) + start], fps)


def preset_sigma(preset: str) -> Duration:
    """The base scale of a preset ("low" or "high") in seconds."""
    return Duration.seconds(PRESETS[preset][0] / REFERENCE_FPS)


def resolve_params(sigma: DurationLike | None, k: int | None, preset: str, contact: bool,
                   fps: float = REFERENCE_FPS) -> tuple[float, int]:
    """Check parameters and fill sigma / k from a resolved preset ("low" or "high"): sigma
    in frames at `fps` (a plain number is already frames; the presets' are in seconds, at
    least half a frame), and k."""
    if preset not in PRESETS:
        raise UsageError(f"saliency: preset must be 'auto', 'low' or 'high', got {preset!r}")
    k0 = PRESETS[preset][1]
    if sigma is None:
        sigma = max(0.5, frames_at(preset_sigma(preset), fps))
    else:
        given = sigma
        try:
            sigma = frames_at(sigma, fps)
        except (TypeError, ValueError):
            raise UsageError(f"saliency: sigma must be a number of frames or a Duration, "
                             f"got {given!r}") from None
        if not (np.isfinite(sigma) and sigma >= 0.5):
            raise UsageError(f"saliency: sigma must be >= 0.5 frames, got {given} "
                             f"({sigma:g} frames at {fps:g} Hz)")
    k = k0 if k is None else k
    if isinstance(k, bool) or not isinstance(k, (int, np.integer)) or k < 1:
        raise UsageError(f"saliency: k must be a positive integer, got {k!r}")
    if contact and k < 3:
        raise UsageError("saliency: contact handling replaces two curves; it needs k >= 3")
    return sigma, int(k)


# --------------------------------------------------------------------------- offline

@dataclass
class _Curves:
    """Everything computed before clustering, for `extract` and diagnostics."""

    d: np.ndarray
    s: np.ndarray
    weights: np.ndarray
    foot: np.ndarray
    basis: Basis


def _rotations(motion: Motion, features: Features) -> np.ndarray:
    return features.rotations[motion.first_frame :]  # unwrapped from the first captured row


def _curves(xs: np.ndarray, feet: np.ndarray, sigma: float, k: int, contact: bool,
            variance_rule: bool, fps: float) -> _Curves:
    basis = pca_basis(moments(xs), k, variance_rule)
    basis = fit_k(basis, k, contact)
    d = curves_of(basis, xs, feet, contact)
    s = maps_of(curvature(d, time_step(fps)), sigma, contact, frames_at(FOOT_SIGMA, fps))
    weights, foot = curve_weights(basis, contact)
    return _Curves(d, s, weights, foot, basis)


def extract(motion: Motion, *, sigma: DurationLike | None = None, k: int | None = None,
            contact: bool = True, preset: str = "auto", variance_rule: bool = False,
            features: Features | None = None,
            noise_cutoff_hz: float | None = DEFAULT_NOISE_CUTOFF_HZ) -> Keyframes:
    """Keyframes of `motion` by multiscale motion saliency (Halit & Capin);
    `sigma` a `Duration`, or frames as a plain number."""
    if preset not in ("auto", *PRESETS):
        raise UsageError(f"saliency: preset must be 'auto', 'low' or 'high', got {preset!r}")
    if features is None:
        features = compute_features(motion, noise_cutoff_hz=noise_cutoff_hz)
    first = motion.first_frame
    speed = None
    used = preset
    if preset == "auto":
        used, speed = choose_preset(features, first)
    fps = motion.fps
    sigma, k = resolve_params(sigma, k, used, contact, fps)
    params: dict[str, Any] = {"sigma": sigma, "sigma_s": sigma / fps, "k": k,
                              "contact": contact, "preset": used,
                              "variance_rule": variance_rule,
                              "foot_sigma": frames_at(FOOT_SIGMA, fps),
                              "cluster_max": cluster_size(sigma)}
    info: dict[str, Any] = {"preset_requested": preset, "preset": used, "mean_speed": speed}
    n = motion.n_frames - first
    if n < 3:
        return Keyframes(METHOD, [], [], params, motion.n_frames, info)
    rot = _rotations(motion, features)
    xs = rot - rot[0]
    feet = features.foot_heights[first:] / features.body_height
    cv = _curves(xs, feet, sigma, k, contact, variance_rule, fps)
    a, thr = normalisation(map_stats(cv.s))
    sal = combine(cv.s, a)
    cand = sal > thr
    rel = sal / np.where(thr > 0, thr, 1.0)
    res = cluster_keyframes(cand, cv.weights, cv.foot, cluster_length(sigma), rel)
    params["k_used"] = len(cv.weights)
    info.update(_info(cv, cand, res, thr, first))
    return Keyframes(METHOD, res["key"] + first, res["score"], params, motion.n_frames, info)


def _info(cv: _Curves, cand: np.ndarray, res: dict[str, np.ndarray], thr: np.ndarray,
          first: int) -> dict[str, Any]:
    clusters = [{"start": int(s) + first, "end": int(e) + first, "keyframe": int(f) + first,
                 "foot": bool(ft), "score": float(sc)}
                for s, e, f, ft, sc in zip(res["start"], res["end"], res["key"], res["foot"],
                                           res["score"], strict=True)]
    kinds = ["pca"] * len(cv.weights)
    if cv.foot.any():
        kinds[-2:] = ["left_foot", "right_foot"]
    return {
        "clusters": clusters,
        "candidates": [np.flatnonzero(cand[:, j]) + first for j in range(cand.shape[1])],
        "foot_candidates": np.flatnonzero(cand[:, cv.foot].any(axis=1)) + first,
        "curve_kinds": kinds, "weights": cv.weights, "thresholds": thr,
        "eigenvalues": cv.basis.values, "explained_variance": cv.basis.explained,
        "kept_columns": len(cv.basis.keep),
    }


# --------------------------------------------------------------------------- online

def _frames(value: DurationLike, fps: float, name: str, whole: bool = False) -> int:
    """A duration parameter of the online keyframer in whole frames at `fps` (>= 1); a plain
    number is frames (an integer if `whole`)."""
    kinds = (Duration, int, np.integer) if whole else (Duration, int, float, np.number)
    if isinstance(value, bool) or not isinstance(value, kinds):
        raise UsageError(f"saliency online: {name} must be a "
                         f"{'whole ' if whole else ''}number of frames or a Duration, "
                         f"got {value!r}")
    frames = whole_frames(value, fps)
    if not frames >= 1:
        raise UsageError(f"saliency online: {name} must be >= 1 frame, got {value}")
    return frames



@dataclass
class _Spread:
    """A basis update in progress (`Online._spread_step`): due at frame u, the moments of
    its window w0..u (rows copied); the window at the switch (frame u + SPREAD - 1) starts
    at frame lo, and the basis decides from frame u + SPREAD on."""

    u: int
    w0: int
    lo: int
    mom: Moments
    xs: np.ndarray
    ft: np.ndarray
    corr: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None = None
    basis: Basis | None = None
    perm: np.ndarray | None = None
    d: np.ndarray | None = None
    c: np.ndarray | None = None
    s: np.ndarray | None = None
    maps: int = 0
    staged: dict[str, Any] | None = None  # the state after the switch (`Online._stage`)


class Online(OnlineKeyframer):
    """Online multiscale saliency: `push` frames, get keyframe events within `lookahead`.

    Running statistics replace the global ones (module docstring). Between basis updates a
    new frame costs one projection, one curvature row and one row of maps (compiled loops,
    `saliency_math.ring_curves` / `ring_maps_of`), computed in `idle()` after its decisions (or
    first thing at the next frame), so that a deciding frame computes its own row only; a
    basis update's work runs in `idle()` too. A deciding frame classifies and clusters its
    due rows in one compiled loop (`saliency_math.classify_block`, the bits of the numpy
    maths). Memory is a ring of `window` frames.

    Timing: the maps of frame f need frames up to f + `radius` + 1. Frames are classified
    (candidate or not, with the statistics of that moment) in order and as late as allowed: a
    cluster starting at frame c0 (at most 2 sigma frames) is classified and closed when frame
    c0 + lookahead arrives, and a frame that may start one waits until its own f + lookahead.
    Hence every event has latency_frames <= lookahead, warm-up included, and a lookahead of at
    least the stream's length leaves every decision to `flush()`. The default lookahead is
    radius + 1 + 2 sigma, the method's support: 121 frames at sigma = 10, 37 at sigma = 3 with
    contact. Any lookahead >= 1 is accepted: below the support, frames are decided from
    Gaussian windows cut at the newest frame and clusters closed at their deadline (module
    docstring), so latency_frames <= lookahead still holds; agreement with offline degrades.
    """

    method = METHOD

    def __init__(self, skeleton: Skeleton, fps: float, *, sigma: DurationLike | None = None,
                 k: int | None = None, contact: bool = True, preset: str = "low",
                 variance_rule: bool = False, lookahead: DurationLike | None = None,
                 update_every: DurationLike = UPDATE_EVERY,
                 history: DurationLike | None = None, stream: str = "default",
                 role_mapping: dict[str, str] | None = None,
                 max_bridge_frames: int = DEFAULT_MAX_BRIDGE_FRAMES) -> None:
        if preset not in PRESETS:
            raise UsageError("saliency online: preset must be 'low' or 'high' (the 'auto' rule "
                             f"needs the whole motion), got {preset!r}")
        sigma, k = resolve_params(sigma, k, preset, contact, fps)
        self.sigma, self.k, self.contact, self.variance_rule = sigma, k, contact, variance_rule
        self.foot_sigma = frames_at(FOOT_SIGMA, fps)
        self.step = time_step(fps)
        self._h2, self._hh = 2.0 * self.step, self.step * self.step
        self.radius = support_radius(sigma, contact, self.foot_sigma)
        self.cmax = cluster_size(sigma)  # the longest cluster, whole frames
        self.clen = cluster_length(sigma)  # where runs are cut (`saliency_math.cuts`)
        self.min_lookahead = self.radius + 1 + self.cmax  # the support: the default
        look = (self.min_lookahead if lookahead is None
                else _frames(lookahead, fps, "lookahead", whole=True))
        every = _frames(update_every, fps, "update_every")
        hist = (int(round(HISTORY_SECONDS * float(fps))) if history is None
                else _frames(history, fps, "history"))
        self.update_every = every
        params = {"sigma": sigma, "sigma_s": sigma / fps, "k": k, "contact": contact,
                  "preset": preset, "variance_rule": variance_rule,
                  "foot_sigma": self.foot_sigma, "cluster_max": self.cmax,
                  "update_every": self.update_every, "history": hist}
        super().__init__(skeleton, fps, lookahead=look, stream=stream,
                         role_mapping=role_mapping, max_bridge_frames=max_bridge_frames,
                         params=params)
        # Frames kept: the decision window, and at least `history` (default 10 s) so that a new
        # basis recomputes the maps and statistics of the recent past consistently.
        self.window = max(max(self.lookahead, self.radius) + self.radius + 2, hist)
        # main-curve kernels in columns 0-7, foot-curve kernels in columns 8-15
        self._bank2 = np.hstack([kernel_bank(sigma, self.radius),
                                 kernel_bank(self.foot_sigma, self.radius)])
        full = self._bank2 / self._bank2.sum(axis=0)
        self._diff_bank = np.hstack([full[:, 0:4] - full[:, 4:8], full[:, 8:12] - full[:, 12:16]])
        self._m = len(skeleton.rotation_columns())
        self.reset()

    # ------------------------------------------------------------------ state
    def reset(self) -> None:
        """Forget the window and running statistics (a new stream starts)."""
        self.t = -1
        self.inc_t = -1  # newest frame whose incremental rows are computed (`_catch_up`)
        self.seq0 = 0
        self.x0: np.ndarray | None = None
        self.basis: Basis | None = None
        self.weights = np.zeros(0)
        self._wsum = 1e-300  # max(sum of the weights, tiny), set with each basis
        self.footmask = np.zeros(0, dtype=bool)
        self.out_mom = Moments(0, np.zeros(self._m), np.zeros((self._m, self._m)))
        self.out_st = MapStats.empty(0)
        self.st = MapStats.empty(0)
        self.warm: MapStats | None = None
        self.out_upto = 0
        self.s_ready = 0
        self.n_class = 0
        self.next_update = 0
        self.cap = min(2 * self.window, 512)
        self.base = 0
        self.buf: dict[str, np.ndarray] = {
            "xs": np.zeros((self.cap, self._m)), "ft": np.zeros((self.cap, 2)),
            "tm": np.zeros(self.cap)}
        self.clusterer = Clusterer(self.clen)
        self._norm: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
        self._foot_rows = np.zeros((0, 1), dtype=bool)
        self._pick = np.zeros(0, dtype=np.int64)
        self._bank_cols = np.zeros(0, dtype=np.int64)
        self._proj: tuple[np.ndarray, ...] = ()
        # (seq, saliency) of each frame as it is classified, for live views: the weighted
        # mean of S_j(f) / mean(S_j) over the curves (> 1 on a candidate of every curve).
        self.trace: deque[tuple[int, float]] = deque(maxlen=TRACE_FRAMES)
        self.resume_at = 0  # after a restart with kept statistics: first frame to analyse
        self.spread: _Spread | None = None  # a spread basis update in progress
        self.deferred = False  # the newest frame's deferred work (`_deferred`) is pending

    def restart(self, keep_statistics: bool = True) -> None:
        """A new window after a long gap or a source restart (after `finish()`): the basis,
        the PCA moments and the map statistics of every frame so far carry over, so the new
        window's frames are classified with them (no second warm-up); the reference row
        `x0` too, as the moments are taken about it. Without them: `reset()`."""
        if not keep_statistics or self.basis is None:
            self.reset()
            return
        a, e = self.out_upto - self.base, self.t - self.base + 1
        mom = self.out_mom + moments(self.buf["xs"][a:e])
        kept = self.st, self.basis, self.weights, self.x0, self.trace
        self.reset()
        self.out_st, self.basis, self.weights, self.x0, self.trace = kept
        self.out_mom = mom
        self._new_basis(mom)  # the same PCA matched to the kept basis: weights, ring arrays
        self.st = self.out_st
        # Like a stream start (first analysis at `lookahead`, or once the maps' support is in),
        # but then every decision uses the carried statistics.
        self.resume_at = min(self.radius + 1, self.lookahead)

    def _alloc_curves(self, kk: int, perm: np.ndarray | None) -> None:
        """(Re)allocate the per-curve ring arrays for `kk` curves, remapping kept columns."""
        b = self.buf
        old = {n: b[n] for n in ("d", "c", "s", "lm") if n in b}
        b["d"] = np.zeros((self.cap, kk))
        b["c"] = np.zeros((self.cap, kk))
        if perm is not None and "s" in old:
            b["s"] = remap(old["s"], perm)
            b["lm"] = remap(old["lm"], perm)
        else:
            b["s"] = np.zeros((self.cap, kk, 4))
            b["lm"] = np.zeros((self.cap, kk, 4), dtype=bool)

    def _room(self, t: int) -> None:
        """Make row `t` writable: shift the ring (or grow it) after folding old rows out."""
        if t - self.base < self.cap:
            return
        lo = max(self.base, t - self.window + 1)
        self._fold_out(lo)
        keep = t - lo
        cap = self.cap if keep <= self.cap // 2 else 2 * self.cap
        for name, arr in self.buf.items():
            new = np.zeros((cap,) + arr.shape[1:], dtype=arr.dtype)
            new[:keep] = arr[lo - self.base : t - self.base]
            self.buf[name] = new
        self.base, self.cap = lo, cap

    def _fold_out(self, upto: int) -> None:
        """Add rows [out_upto, upto) to the totals of frames that left the window."""
        if upto <= self.out_upto:
            return
        a, b = self.out_upto - self.base, upto - self.base
        self.out_mom = self.out_mom + moments(self.buf["xs"][a:b])
        if self.basis is not None:
            self.out_st = self.out_st + map_stats(self.buf["s"][a:b], self.buf["lm"][a:b])
        self.out_upto = upto

    # ------------------------------------------------------------------ stream
    def process(self, block: FeatureBlock) -> list[KeyframeEvent]:
        """Advance over clean consecutive frames (called by push / push_block)."""
        if len(block) == 0:
            return []
        if self.t < 0:  # a new window (stream start or restart)
            self.seq0 = int(block.seq[0])
            if self.x0 is None:
                self.x0 = block.rotations[0].copy()
        xs = block.rotations - self.x0
        feet = block.foot_heights / self.features.body_height
        events: list[KeyframeEvent] = []
        for i in range(len(block)):
            events.extend(self._advance(xs[i], feet[i], float(block.time[i])))
        return events

    def _advance(self, x: np.ndarray, foot: np.ndarray, time: float) -> list[KeyframeEvent]:
        if self.deferred:  # `idle()` was not called after the last frame
            self._deferred()
        if self.spread is not None and self.spread.staged is not None:
            self.__dict__.update(self.spread.staged)  # the switch: the new basis decides
        self.t += 1
        t = self.t
        if t - self.base >= self.cap:
            self._catch_up(t - 1)  # before the first basis (else `_deferred` made room)
            self._room(t)
        r = t - self.base
        b = self.buf
        b["xs"][r] = x
        b["ft"][r] = foot
        b["tm"][r] = time
        if self._update_due(t):  # the first basis; later ones below 3 frames (else made
            # early by `_deferred`)
            self._catch_up(t - 1)
            self._update(final=False)
        self.deferred = True
        if self.basis is None or t < self.resume_at:  # restarted: the window fills first
            return []
        return self._classify_due(t)

    def idle(self) -> list[KeyframeEvent]:
        """The last frame's deferred work (`_deferred`); it decides nothing."""
        if self.deferred:
            self._deferred()
        return []

    def _update_due(self, t: int) -> bool:
        """Whether frame t's decisions need a basis update made at once: the first of a
        window (frame `lookahead`, or `resume_at` after a restart), or one not spread."""
        if self.basis is None:
            return t >= self.lookahead
        if t < self.resume_at or self.spread is not None:
            return False
        return t + 1 >= self.next_update and not self._spreads(t)

    def _deferred(self, early: bool = True) -> None:
        """Work of frame t that no decision of frame t reads, run after them (`idle()`, or
        first thing at the next frame): an update made at once that frame t + 1 needs
        (not the first basis, made in frame `lookahead`'s push), from the frames up to t
        (`early`); else frame t's incremental rows (so that the
        next deciding frame computes only its own), a piece of a spread basis update or
        its start, a piece of the past folded into the totals, room for the next row."""
        self.deferred = False
        t = self.t
        if early and t >= 2 and self.basis is not None and self._update_due(t + 1):
            self._catch_up(t)
            self._update(final=False)
            return
        if self.basis is None or t < self.resume_at:
            return
        self._catch_up(t)
        if t + 1 - self.base >= self.cap:
            self._room(t + 1)
        if self.spread is not None:
            self._spread_step(t)
        elif t + 1 >= self.next_update:  # `_spreads(t)`: else it was made at once
            self._spread_start(t)
        elif min(t - self.window + 1, self.s_ready - 1) - self.out_upto >= FOLD_EVERY:
            self._fold_out(self.out_upto + FOLD_EVERY)  # the past in small pieces

    def _spreads(self, t: int) -> bool:
        """Whether a basis update due at frame t is spread over `SPREAD` frames rather than
        made at once: every one but the first of a window (`lookahead`, or `resume_at`),
        once frame t holds the support of the stream-start rows' maps (frame 2 radius + 2)."""
        return self.window > SPREAD + 2 * self.radius + 2 and t >= 2 * self.radius + 2

    def _catch_up(self, upto: int) -> None:
        """The incremental rows (curve, curvature, maps, statistics) of frames up to `upto`.

        They are computed when something reads them (a classification, a basis update, the
        ring moving), for all frames since the last time at once, in compiled loops that go
        frame by frame (`ring_curves`, `ring_maps_of`): the same bits whatever the split."""
        p = self.inc_t + 1
        if self.basis is None or upto < p or p == 0:  # p == 0: a window restarted with the
            return  # basis kept, before its first analysis (`_update` makes every row)
        self.inc_t = upto
        R = self.radius
        if p <= 2 * R + 1:  # stream start: the edge rules, frame by frame
            for t in range(p, upto + 1):
                self._incremental(t)
            return
        b, base = self.buf, self.base
        self._curve_rows(p, upto)
        f0, f1 = max(self.s_ready, p - R - 1), upto - R - 1
        if f1 < f0:
            return
        st = self.st
        st.n += f1 - f0 + 1
        ring_maps_of(b["c"], b["s"], b["lm"], f0 - base, f1 - base, self._diff_bank,
                     self._bank_cols, st.total, st.top, st.lm_n, st.lm_sum, st.lm_top)
        self.s_ready = f1 + 1
        self._norm = None

    def _window_maps(self, c: np.ndarray, r0: int, n: int, pick: np.ndarray, out: np.ndarray
                     ) -> None:
        """Maps (n, k, 4) into `out` of n frames from the curvatures `c` (contiguous rows):
        frame i's Gaussian windows are rows r0 + i .. r0 + i + 2 radius (one product)."""
        row = c.strides[0]
        win = np.ndarray((n, c.shape[1], 2 * self.radius + 1), c.dtype, c, r0 * row,
                         (row, c.strides[1], row))  # a sliding window view, without its checks
        np.abs((win @ self._diff_bank).reshape(n, -1)[:, pick], out=out.reshape(n, -1))

    def _curve_rows(self, p: int, upto: int) -> None:
        """Curve rows of frames p..upto and curvature rows of frames p-1..upto-1."""
        b, base = self.buf, self.base
        keep, mean, sd, vec = self._proj
        ring_curves(b["xs"], b["ft"], keep, mean, sd, vec, self.contact, b["d"], b["c"],
                    p - base, upto - base + 1, self.step)

    def _peek(self, upto: int) -> None:
        """Curve rows up to `upto` for the provisional candidates only, without catching up
        (`_catch_up` writes the same rows again), so decisions and scores never depend on
        who read when."""
        p = self.inc_t + 1
        if self.basis is None or upto < p or p == 0:  # p == 0: a restarted window, no rows yet
            return
        if p <= 2 * self.radius + 1:  # stream start: `_catch_up` goes frame by frame
            for t in range(p, upto + 1):
                self._curve_row(t)
        else:
            self._curve_rows(p, upto)

    def _classify_due(self, t: int) -> list[KeyframeEvent]:
        """Classify the frames whose deadline has come: a cluster starting at c0 (or a frame
        that may start one) is classified, and closed, when frame c0 + lookahead arrives.

        Below the support, frames past t - radius - 1 are classified from maps cut at frame t
        (`truncated_maps`), and a cluster still open at its deadline is closed there."""
        rows = self.clusterer.rows
        if t < (rows[0] if rows else self.n_class) + self.lookahead:
            return []  # nothing is due: the incremental rows can wait
        self._catch_up(t)
        events: list[KeyframeEvent] = []
        g, ready = self.n_class, t - self.radius - 1
        edge: tuple[int, np.ndarray] | None = None
        if g <= min(t, ready) and t >= (rows[0] if rows else g) + self.lookahead:
            # Frames with stored maps, as one block: the statistics do not change meanwhile.
            events.extend(self._classify(g, min(t, ready), due=t))
            g = self.n_class
        while g <= t:
            rows = self.clusterer.rows
            if t < (rows[0] if rows else g) + self.lookahead:
                break
            s = None
            if g > ready:  # only below the support
                edge = edge or self._edge_curvatures(t)
                s = truncated_maps(edge[1], self._bank2, np.array([g - edge[0]]),
                                   self.footmask)
            events.extend(self._classify(g, g, s))
            g += 1
        rows = self.clusterer.rows
        if rows and t >= rows[0] + self.lookahead:
            events.extend(self._emit([self.clusterer.close()]))
        return events

    def _edge_curvatures(self, t: int) -> tuple[int, np.ndarray]:
        """(first frame, curvatures up to frame t) as if the clip ended at t (eq. 3.4 ends)."""
        lo = max(0, t - 2 * self.radius)
        b = self.buf
        cs = b["c"][lo - self.base : t - self.base + 1].copy()
        r = t - self.base
        cs[-1] = end_curvature(b["d"][r - 2 : r + 1], self.step) if t >= 2 else 0.0
        return lo, cs

    def finish(self) -> list[KeyframeEvent]:
        """End of stream: final basis from every frame, then decide every pending frame."""
        if self.deferred:
            self._deferred(early=False)  # the final update comes next
        if self.t < 2:
            return []
        self._catch_up(self.t)
        self._update(final=True)
        events = self._classify(self.n_class, self.t)
        if self.clusterer.rows:
            events.extend(self._emit([self.clusterer.close()]))
        return events

    # ------------------------------------------------------------------ maths
    def _update(self, final: bool, spread: _Spread | None = None) -> None:
        """New basis from the running moments; recompute the window's curves and maps. With
        `spread`, the basis and most rows come from the spread update (`_spread_step`)."""
        t = self.t
        # (the ring may already have moved on for frame t + 1: its first row is then the
        # window's first, the one before folded into the totals)
        w0 = max(0, t - self.window + 1, self.base) if spread is None else spread.lo
        self._fold_out(w0)
        a, e = w0 - self.base, t - self.base + 1
        b = self.buf
        self.spread = None
        if spread is None:
            self._new_basis(self.out_mom + moments(self.buf["xs"][a:e]))
            assert self.basis is not None
            d = curves_of(self.basis, b["xs"][a:e], b["ft"][a:e], self.contact)
            c = curvature(d, self.step)
            s = maps_of(c, self.sigma, self.contact, self.foot_sigma)
        else:
            d, c, s = self._spread_rows(spread, a, e)
        b["d"][a:e], b["c"][a:e] = d, c
        # Rows whose Gaussian windows lie inside the window (all of them at stream start) get
        # new maps; older rows keep theirs. At flush the stream's end is a real end.
        hi = t if final else t - self.radius - 1
        lo = w0 if w0 == 0 else w0 + self.radius + 1
        if hi >= lo:
            b["s"][lo - self.base : hi - self.base + 1] = s[lo - w0 : hi - w0 + 1]
        h = hi - self.base + 1
        if hi >= w0:
            mask = local_max_mask(b["s"][a:h])
            b["lm"][a + 1 : h - 1] = mask[1:-1]
            b["lm"][h - 1] = False
            if w0 == 0:
                b["lm"][a] = False
        self.s_ready = max(hi + 1, 0)
        self.st = self.out_st + map_stats(b["s"][a:h], b["lm"][a:h])
        # Below the support, early frames are decided before (almost) any final map exists:
        # until the final maps cover as many frames, normalise with the maps cut at frame t.
        self.warm = None
        if not final and self.lookahead < self.min_lookahead and w0 == 0 and (
                hi < self.radius):
            self.warm = map_stats(s)
        self._norm = None
        self.inc_t = t
        if spread is None:
            self.next_update = t + 1 + min(t + 1, self.update_every)

    def _spread_rows(self, sp: _Spread, a: int, e: int
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Switch to the spread update's basis; curves, curvatures and maps of the window
        (ring rows a..e-1, frames lo .. u + SPREAD - 1): the spread's rows, completed by the
        frames after u and the maps that reach them."""
        assert sp.basis is not None and sp.d is not None and sp.c is not None
        assert sp.s is not None
        self._set_basis(sp.basis, sp.perm)
        b, R, n = self.buf, self.radius, len(sp.d)
        d_new = curves_of(sp.basis, b["xs"][a + n : e], b["ft"][a + n : e], self.contact)
        d = np.concatenate([sp.d, d_new])
        c_new = curvature(d[n - 2 :], self.step)  # frames u - 1 .. t; the first: an edge row
        c = np.concatenate([sp.c[: n - 1], c_new[1:]])
        s = np.concatenate([sp.s, np.zeros((e - a - n,) + sp.s.shape[1:])])
        f0 = sp.maps - sp.lo  # first window row without maps yet
        cnt = len(c) - R - f0  # up to frame t - radius (the windows inside the window)
        if cnt > 0:
            self._window_maps(c, f0 - R, cnt, self._pick, s[f0 : f0 + cnt])
        return d, c, s

    def _new_basis(self, mom: Moments) -> None:
        """PCA of the moments, matched to the previous basis; per-curve state follows it."""
        self._set_basis(*self._pca(mom))

    def _pca(self, mom: Moments) -> tuple[Basis, np.ndarray | None]:
        """The basis of the moments matched to the current one, and `perm` (`match_basis`;
        None for the first basis). Changes no state."""
        return self._match(fit_k(pca_basis(mom, self.k, self.variance_rule), self.k,
                                 self.contact))

    def _match(self, new: Basis | None) -> tuple[Basis, np.ndarray | None]:
        """`new` matched to the current basis (`match_basis`), and `perm` (None: no basis)."""
        assert new is not None
        if self.basis is None:
            return new, None
        feet = 2 if self.contact else 0
        kk = new.vectors.shape[1]
        return match_basis(self.basis, new, len(self.weights) - feet, kk - feet)

    def _set_basis(self, new: Basis, perm: np.ndarray | None) -> None:
        """Switch to the basis `new` (`_pca`): statistics and ring columns follow its curves."""
        feet = 2 if self.contact else 0
        kk = new.vectors.shape[1]
        if perm is not None:
            self.out_st = remap_stats(self.out_st, perm)
        elif self.out_st.top.shape[0] != kk:
            self.out_st = MapStats.empty(kk)
        same = "d" in self.buf and self.buf["d"].shape[1] == kk and (
            perm is None or np.array_equal(perm, np.arange(kk)))
        if not same:  # the curves moved columns (or their count changed): new ring arrays
            self._alloc_curves(kk, perm)
        self.basis = new
        self.weights, self.footmask = curve_weights(new, self.contact)
        self._wsum = max(float(self.weights.sum()), 1e-300)
        self._foot_rows = self.footmask[:, None]
        self._pick = self._pick_of(new)
        cols = self._pick.reshape(kk, 4) - 8 * np.arange(kk)[:, None]  # `_diff_bank` columns
        self._bank_cols = np.ascontiguousarray(cols[:, 0])  # each curve's `_diff_bank` columns
        self._proj = (new.keep, new.mean[new.keep], new.sd[new.keep],
                      np.ascontiguousarray(new.vectors[:, : kk - feet]))

    # ------------------------------------------------------------------ spread update
    def _spread_start(self, u: int) -> None:
        """A basis update due at frame u (after its decisions): fold the window's past out
        and keep a copy of the window's rows; the work follows one piece a frame
        (`_spread_step`, in `idle()`), the switch at frame u + `SPREAD` - 1, so that the
        new basis decides from frame u + `SPREAD` on (module docstring)."""
        self._catch_up(u)
        w0 = max(0, u - self.window + 1, self.base)  # (as `_update`'s)
        lo = max(0, u + SPREAD - self.window)  # the window's start at the switch
        self._fold_out(w0)
        a, e = w0 - self.base, u - self.base + 1
        self.spread = _Spread(u, w0, lo, self.out_mom, self.buf["xs"][a:e].copy(),
                              self.buf["ft"][lo - self.base : e].copy())
        self.next_update = u + 1 + min(u + 1, self.update_every)

    def _spread_step(self, t: int) -> None:
        """One piece of the spread update (the window's moments, the PCA, its curves, a
        block of maps), or the switch at its last frame."""
        sp = self.spread
        assert sp is not None
        v = sp.u + SPREAD - 1  # the switch, staged for the next frame
        if t >= v:
            self._stage(sp)
            return
        k = t - sp.u
        if k == 1:
            sp.mom = sp.mom + moments(sp.xs)
        elif k == 2:
            sp.corr = correlation(sp.mom)
        elif k == 3:
            assert sp.corr is not None
            sp.basis = fit_k(components(sp.corr, self.k, self.variance_rule), self.k,
                             self.contact)
        elif k == 4:
            sp.basis, sp.perm = self._match(sp.basis)
        elif k in (5, 6):  # curves of frames lo .. u, half of them a frame
            n = len(sp.ft)
            h = n // 2
            rows = slice(0, h) if k == 5 else slice(h, n)
            assert sp.basis is not None
            d = curves_of(sp.basis, sp.xs[sp.lo - sp.w0 :][rows], sp.ft[rows], self.contact)
            if k == 5:
                sp.d = np.empty((n, d.shape[1]))
            assert sp.d is not None
            sp.d[rows] = d
        elif k == 7:  # their curvatures (the last row, frame u's: at the switch)
            assert sp.d is not None
            sp.c = curvature(sp.d, self.step)
            sp.s = np.zeros((len(sp.d), sp.d.shape[1], 4))
            sp.maps = sp.lo + self.radius + 1 if sp.lo > 0 else 0  # next frame to map
        elif sp.maps == 0:  # stream start: the first radius rows, windows cut at frame 0
            assert sp.c is not None and sp.s is not None
            R = self.radius
            sp.s[:R] = maps_of(sp.c[: 2 * R], self.sigma, self.contact, self.foot_sigma)[:R]
            sp.maps = R
        else:  # maps of frames whose Gaussian windows end before frame u, a block a frame
            assert sp.c is not None and sp.s is not None
            f0, last = sp.maps, sp.u - 1 - self.radius
            f1 = min(last, f0 + -(-(last - f0 + 1) // (v - t)) - 1)
            if f1 >= f0:
                lo = sp.lo
                self._window_maps(sp.c, f0 - self.radius - lo, f1 - f0 + 1,
                                  self._pick_of(sp.basis), sp.s[f0 - lo : f1 - lo + 1])
                sp.maps = f1 + 1

    def _stage(self, sp: _Spread) -> None:
        """The switch of a spread update (`_update`), made on a copy of the state at frame
        u + `SPREAD` - 1 (in `idle()`) and swapped in by the next frame, before its
        decisions: no decision reads it earlier, and the basis changes with that frame."""
        new = copy.copy(self)
        new.buf = {name: arr.copy() if name in ("d", "c", "s", "lm") else arr
                   for name, arr in self.buf.items()}
        new._update(final=False, spread=sp)
        sp.staged = new.__dict__

    def _pick_of(self, basis: Basis | None) -> np.ndarray:
        """Flat index of each curve's four maps in the (k, 8) product of `_window_maps`: foot
        curves take columns 4-7."""
        assert basis is not None
        foot = curve_weights(basis, self.contact)[1]
        kk = len(foot)
        flat: np.ndarray = (np.arange(kk)[:, None] * 8 + np.arange(4) + 4 * foot[:, None]).ravel()
        return flat

    def _incremental(self, t: int) -> None:
        """One new frame between basis updates: its curve row, one curvature, one map row."""
        self._curve_row(t)
        f = t - self.radius - 1
        if f < self.s_ready:
            return
        self._map_row(f)

    def _curve_row(self, t: int) -> None:
        """Frame t's curve row and frame t-1's curvature (frame by frame)."""
        b, r = self.buf, t - self.base
        keep, mean, sd, vec = self._proj
        row = b["d"][r]
        row[: vec.shape[1]] = ((b["xs"][r, keep] - mean) / sd) @ vec
        if self.contact:
            row[-2:] = b["ft"][r]
        dd = b["d"][r - 2 : r + 1]
        d1 = np.subtract(dd[2], dd[0])
        d1 /= self._h2
        num = dd[2] - 2.0 * dd[1]
        num += dd[0]
        num /= self._hh
        den = np.multiply(d1, d1, out=d1)
        den += 1.0
        np.divide(np.abs(num, out=num), np.power(den, 1.5, out=den), out=b["c"][r - 1])
        if t == 2:  # first frame: D' one-sided, D'' copied from frame 1 (as `curvature`)
            d1 = (dd[1] - dd[0]) / self.step
            b["c"][0] = np.abs((dd[2] - 2.0 * dd[1] + dd[0]) / self._hh) / (
                1.0 + d1 * d1) ** 1.5

    def _map_row(self, f: int) -> None:
        """Maps S_i of frame f from the curvatures f-radius..f+radius (start-truncated)."""
        b, R = self.buf, self.radius
        lo = max(0, f - R)
        cs = b["c"][lo - self.base : f + R + 1 - self.base]
        rf = f - self.base
        if lo > 0:  # G(s_i) - G(2 s_i) is one linear filter: one product for all eight maps
            s = b["s"][rf]
            np.abs((cs.T @ self._diff_bank).reshape(-1)[self._pick], out=s.reshape(-1))
        else:  # stream start: weights renormalised over the frames that exist
            bank = self._bank2[R - f :]
            g = cs.T @ bank / bank.sum(axis=0)
            g = np.where(self._foot_rows, g[:, 8:], g[:, :8])
            s = np.abs(g[:, :4] - g[:, 4:])
            b["s"][rf] = s
        st = self.st
        st.n += 1
        st.total += s
        np.maximum(st.top, s, out=st.top)
        if f >= 2:
            prev, mid = b["s"][rf - 2], b["s"][rf - 1]
            flag = (mid > prev) & (mid >= s)
            b["lm"][rf - 1] = flag
            st.lm_n += flag
            peak = mid * flag
            st.lm_sum += peak
            np.maximum(st.lm_top, peak, out=st.lm_top)
        self.s_ready = f + 1
        self._norm = None

    def _classify(self, g0: int, g1: int, s: np.ndarray | None = None,
                  due: int | None = None) -> list[KeyframeEvent]:
        """Candidates of frames g0..g1 with the current statistics, fed to the clusterer;
        `s` their maps when not the stored ones. With `due` (the newest frame), stop before
        the first frame not yet due (the open cluster's start, or the frame itself, plus the
        lookahead after `due`)."""
        if s is None:
            s = self.buf["s"][g0 - self.base : g1 - self.base + 1]
        stop = _NO_STOP if due is None else due - self.lookahead
        n, level, closed = self._feed(self.clusterer, s, g0, stop)
        self.trace.extend(zip(range(self.seq0 + g0, self.seq0 + g0 + n), level[:n].tolist(),
                              strict=True))
        self.n_class = g0 + n
        return self._emit(closed)

    def _feed(self, cl: Clusterer, s: np.ndarray, g0: int, stop: int
              ) -> tuple[int, np.ndarray, list[tuple[int, float]]]:
        """Rows g0.. of maps `s` classified with the current statistics and fed to `cl` in
        one compiled loop (`classify_block`), up to the first row whose cluster would start
        after `stop`; `cl` takes the open cluster's new state (new lists: a copy's lists
        stay the original's). Returns (rows taken, their trace levels, clusters closed)."""
        m = self.cmax + 1  # the open cluster, as `classify_block`'s buffers
        rows, wrow, foot = np.zeros(m, dtype=np.int64), np.zeros(m), np.zeros(m, dtype=bool)
        k = len(cl.rows)
        if k:
            rows[:k], wrow[:k], foot[:k] = cl.rows, cl.wrow, cl.foot
        n, level, keys, scores, nk, k, cl.score, cl.last, cl.run = classify_block(
            s, *self._normal(), self.weights, self.footmask, self._wsum, g0, stop, self.clen,
            rows, wrow, foot, k, cl.score, cl.last, cl.run)
        cl.rows, cl.wrow, cl.foot = rows[:k].tolist(), wrow[:k].tolist(), foot[:k].tolist()
        return n, level, list(zip(keys[:nk].tolist(), scores[:nk].tolist(), strict=True))

    def _emit(self, closed: list[tuple[int, float]]) -> list[KeyframeEvent]:
        tm = self.buf["tm"]
        return [self.event(self.seq0 + row, float(tm[row - self.base]), score,
                           self.seq0 + self.t) for row, score in closed]

    def candidates(self) -> list[tuple[int, float, float]]:
        """Provisional hook: the keys that the open cluster and the frames not yet classified
        point to, with the statistics of this moment (nothing decided): frames with final
        maps, then frames with early maps (`_early_maps`). Re-derived every
        `CANDIDATE_EVERY` frames (a clustering over ~100 frames)."""
        if self.basis is None or self.inc_t < 0:  # no analysis in this window yet
            return []
        self._peek(self.t)
        early = self._early_maps(max(self.n_class, self.s_ready))  # one new row a frame
        slot, basis, cached = getattr(self, "_cand", (None, None, []))
        if slot == self.t // CANDIDATE_EVERY and basis is self.basis:
            rows = self.clusterer.rows  # clusters closed since are no longer candidates
            lo = self.seq0 + (rows[0] if rows else self.n_class)
            return [c for c in cached if c[0] >= lo]
        self._cand = (self.t // CANDIDATE_EVERY, self.basis, self._candidates(early))
        return self._cand[2]

    def _normal(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(a, thr, thr with its zeros as 1): the map normalisation of the current
        statistics (the warm-up's while they hold fewer frames), cached until they change."""
        if self._norm is None:
            warm = self.warm
            st = warm if warm is not None and self.st.n < warm.n else self.st
            args = (st.total, st.n, st.lm_n, st.lm_sum, st.lm_top)
            hmax, h3 = getattr(self, "_h3", (np.zeros(0), np.zeros(0)))
            a, thr, safe, ok = (itti_factors(st.top, hmax, h3, *args) if len(hmax) == len(st.top)
                                else (None, None, None, False))
            if not ok:  # a new row maximum (rare): its cube as `normalisation` takes it
                h = st.top.max(axis=1, keepdims=True)
                self._h3 = hmax, h3 = h.reshape(-1), (h**3).reshape(-1)
                a, thr, safe, ok = itti_factors(st.top, hmax, h3, *args)
            self._norm = cast(tuple[np.ndarray, np.ndarray, np.ndarray], (a, thr, safe))
        return self._norm

    def _candidates(self, early: np.ndarray) -> list[tuple[int, float, float]]:
        sim = copy.copy(self.clusterer)  # `_feed` gives it new lists: the clusterer's stay
        closed: list[tuple[int, float]] = []
        lo, hi = self.n_class, self.s_ready
        maps = [self.buf["s"][lo - self.base : max(lo, hi) - self.base], early]
        if len(maps[0]) + len(maps[1]):
            closed = self._feed(sim, np.concatenate(maps), lo, _NO_STOP)[2]
        if sim.rows:
            closed.append(sim.close())
        tm = self.buf["tm"]
        return [(self.seq0 + row, float(tm[row - self.base]), score) for row, score in closed]

    def _early_maps(self, start: int) -> np.ndarray:
        """Maps of the rows start.. that have no final maps yet, each computed once, 2 sigma
        frames after its frame, from windows cut there (the clip-end rule); for provisional
        candidates only, never for decisions or statistics."""
        cache: dict[int, np.ndarray]
        basis, cache = getattr(self, "_early", (None, {}))
        if basis is not self.basis:  # a new basis moves every curve
            cache = {}
        g = self.t - self.cmax
        if g >= start and g not in cache and self.t >= 2:
            lo, cs = self._edge_curvatures(self.t)
            cache[g] = truncated_maps(cs, self._bank2, np.array([g - lo]), self.footmask)[0]
        for row in [r for r in cache if r < start]:
            del cache[row]
        self._early: tuple[Basis | None, dict[int, np.ndarray]] = (self.basis, cache)
        out: list[np.ndarray] = []
        while start + len(out) in cache:
            out.append(cache[start + len(out)])
        return np.array(out).reshape(len(out), len(self.weights), 4)
