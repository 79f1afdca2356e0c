"""Multiscale motion saliency — C. Halit, "A multi scale motion saliency method for keyframe
extraction from motion capture sequences", MSc thesis, Bilkent University, 2010, chapter 3
(journal version: Halit & Capin, Computer Animation and Virtual Worlds, 2011).

Offline: `extract(motion)`. Definitions this module settles (where they differ from the thesis):

- Input (thesis eq. 3.1): the unwrapped rotation channels of the captured frames (root
  position excluded), unwrapped from the first captured frame (as a stream starting there is).
  Every column is standardised over the clip's motion, by sqrt(variance + n^2) with a noise
  floor n = `NOISE_FLOOR_DEG` (0.5 degrees RMS, not in the thesis); columns with variance
  <= 1e-10 deg^2 are dropped. Moments are taken after subtracting the first captured frame
  (less cancellation). Standardising by the variance alone gives every column the weight of
  the body's motion: a joint a clip never moves (22 of 93 columns of 02_10, 07_01) is dropped
  when clean, but with 0.3 degrees of sensor noise it is a unit-variance column of noise, and
  22 of them change the components and the count the variance rule keeps. With the floor a
  column moving much less than half a degree weighs little and a moving one as before.
  Measured on 29 shared BVH clips, F1 against the clean take, offline / online (mean /
  worst): 0.3 degrees of noise 0.866 / 0.725 -> 0.961 / 0.799 and 0.875 / 0.671 -> 0.958 /
  0.801, 1 degree offline 0.841 / 0.711 -> 0.909 / 0.746, 60 Hz online 0.940 / 0.778 ->
  0.947 / 0.865; 30 Hz offline 0.881 / 0.667 -> 0.890 / 0.737, online 0.856 / 0.667 ->
  0.844 / 0.686; calibration before offline 0.874 / 0.738 -> 0.881 / 0.688, online 0.839 /
  0.698 -> 0.835 / 0.686. Tried: a floor of 0.1 degrees (0.3 degrees of noise offline
  0.927 / 0.756, online 0.921 / 0.715), of 1 degree (calibration before offline worst
  0.545), and dropping the columns below 0.5 degrees instead (the same noise figures, but a
  column near the cut is kept or dropped as a calibration blend adds to its variance:
  calibration before offline worst 0.667).
- Motion: the frames inside takes (`streamkey.segments.detect_segments` / `motion_mask`;
  every frame if the clip has no take). Calibration holds and still stretches are not
  motion: they stay out of the moments (PCA) and of the map statistics (normalisation,
  thresholds), and get no candidate, so the keys of a take do not depend on a calibration
  pose before it or stillness after it. Curves, curvatures and maps are computed on every
  frame (a map near a take's edge sees the frames around it).
- PCA (eq. 3.2-3.3): eigen-decomposition of the correlation matrix (the covariance of the
  standardised columns, population normalisation), components by decreasing eigenvalue, each
  eigenvector signed so that its largest-magnitude entry is positive. k components; with
  `variance_rule` k = max(k, smallest k reaching 90 % of the variance) (thesis Fig. 3.2).
- Contact (sec. 3.3): the last two of the k curves are replaced by the left and right ankle height
  divided by body height (unit-free), analysed with sigma = `FOOT_SIGMA` (1/40 s, 3 frames
  at 120 Hz). They take the eigenvalues of
  the two components they replace as cluster weights, so the weights still sum to the
  variance of k components.
- Low-pass of the curves (not in the thesis): their input (the rotation channels and the foot
  heights; the curves are affine in them) goes through a causal 6th-order Butterworth
  low-pass at `CURVE_CUTOFF_HZ` (3.5 Hz), started at rest on the first frame, the same
  recursion offline and online (`saliency_math.smooth_curves`); the moments (PCA) stay raw.
  The curvature of the raw curves is mostly content above the 15 Hz Nyquist frequency of a
  30 Hz take (the mean |D''| falls 3x at 60 Hz, 9x at 30 Hz), so the same motion gave other
  extrema at another rate; a cut-off in Hz makes the curvature describe the motion, not the
  sampling. Measured on 5 shared clips, offline F1 against the clean take (mean / worst):
  60 Hz 0.759 / 0.548 -> 0.978 / 0.966, 30 Hz 0.707 / 0.525 -> 0.934 / 0.862, calibration
  before 0.849 / 0.703 -> 0.912 / 0.754. Causal, so it moves no dependency (the support and
  the lookahead stay). Its delay (~0.1 s) is the same at every rate; the keys mostly stay on
  the 2 sigma cluster grid, so they are not shifted back: on 7 shared clips at 120 Hz, F1
  against the unfiltered keys is 0.67 as they are, 0.45-0.63 shifted back 2-12 frames.
  Re-measured with the 6 Hz noise front end on (29 BVH clips, saliency's 24 goal cells;
  agreement on 35 clips and 7 sessions): without this low-pass 3 fewer cells are met
  (offline 30 Hz key ratio 0.86-1.11 -> 0.67-1.60, 60 Hz F1 0.951 / 0.868 -> 0.907 /
  0.728);
  at 5 Hz 3 fewer (agreement worst 0.697 -> 0.545, key ratio up to 1.50); at 3 Hz one more
  (online 30 Hz key ratio 0.79 -> 0.81) but agreement falls (median 0.828 -> 0.821,
  sessions after 10 s 0.771 -> 0.753) with the key ratio at its 1.25 edge. The front end's
  Gaussian passes 1.3 % at 15 Hz, which the second derivative weighs 25 times more than
  3 Hz: it does not replace this filter, so 3.5 Hz stays.
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
- Candidates (sec. 3.1.3): motion frames with S_j(f) > mean of S_j over the clip's motion,
  per curve j.
- Clusters (sec. 3.1.4): runs of consecutive frames that are a candidate on any curve, cut into
  pieces of at most 2 sigma frames on a grid counted from the first captured frame (a cut
  wherever the frame number crosses a multiple of 2 sigma, `saliency_kernels.cuts`). The
  thesis counts the pieces from each run's start; but about 90 % of the frames are
  candidates, so runs are long and their keys sit at 2 sigma steps from the run's start,
  which a small change of a threshold moves (another rate, a calibration hold, stillness):
  measured on 5 shared clips, offline F1 against the clean take 0.551 -> 0.732 at 60 Hz,
  0.636 -> 0.713 at 30 Hz, 0.680 -> 0.818 after a calibration hold, 0.589 -> 0.798 before
  stillness. On a grid in seconds the slots are the same at any rate.
  Weighted mean frame with one entry per (frame, curve) candidate, weight = the curve's
  eigenvalue; the keyframe is the cluster frame nearest to it (ties within 1e-9 go to the
  earlier frame). A cluster with a foot candidate picks among its foot-candidate frames (sec. 3.3).
- Score: the cluster's saliency, sum over its (frame, curve) candidates of
  weight_j * S_j(f) / mean(S_j), divided by the sum of all k weights.
- Presets (thesis sec. 4.2): "low" sigma = 1/12 s (10 frames at 120 Hz), k = 7; "high"
  sigma = 1/40 s (3 frames), k = 10 (at least half a frame at any rate); "auto" picks "high"
  when the speed of the body is at least `AUTO_SPEED_THRESHOLD` (1.03) body heights per
  second (the runs in the shared data), else "low". A frame step's speed is the mean speed
  of Miura's 16 body parts in the pelvis frame; the body's speed is the `AUTO_QUANTILE`
  (90th) percentile of the moving steps' speeds (mean part speed above `STILL_SPEED`) in
  the first `AUTO_SECONDS` (1 s) from the first moving step on: a calibration hold before
  the take, or stillness after a take shorter than 1 s, counts for nothing. The rule was
  the mean over 2 s (threshold 0.85). A high percentile, because slow steps that are not
  the take's own shift a mean across the threshold: the blend out of a calibration pose
  (0.5 s of the 2 s) took the mean of the three short runs (09_01, 09_06, 02_03) from
  0.86-0.95 to 0.73-0.78, and the stop into stillness after the 1.45 s 02_03 from 0.86 to
  0.82, so they lost two thirds of their keys. One second, because online the "high" keys
  held back until the decision are lost once they are older than the lookahead: decided
  at 2 s, a 1.2-1.5 s run followed by stillness kept about half of its online keys, and
  online agreed with offline on 02_03 at a key ratio of 0.77 (at 1 s: 0.97). On the 35
  shared clips under every standard variant (60 and 30 Hz, 0.3 degrees of noise,
  calibration before, stillness after) the fast takes' value stays >= 1.07 and the
  others' <= 0.98; at 120 Hz every clip keeps the preset of the old rule (05_06, a dance
  whose fast part starts after its first second, stays "low"). The first second makes the
  rule causal, so the online keyframer (`saliency_auto.AutoOnline`) takes the same
  decision. `sigma` and `k` override the preset's values.

Online: `Online` (`saliency_online`, whose docstring states how each global statistic becomes
a running one) and `saliency_auto.AutoOnline` (the "auto" preset).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from ..errors import UsageError
from ..features import DEFAULT_NOISE_CUTOFF_HZ, Features, compute_features
from ..keyframes import Keyframes
from ..motion import Motion, without_lead
from ..segments import detect_segments, motion_mask
from ..units import DurationLike
from .saliency_kernels import pick_keyframe
from .saliency_math import (
    CURVE_CUTOFF_HZ,
    FOOT_SIGMA,
    REFERENCE_FPS,
    SCALES,
    Basis,
    MapStats,
    Moments,
    cluster_keyframes,
    cluster_length,
    cluster_size,
    combine,
    curvature,
    curve_weights,
    curves_of,
    fit_k,
    frames_at,
    gaussian_means,
    kernel,
    kernel_bank,
    local_max_mask,
    map_stats,
    maps_of,
    match_basis,
    moments,
    normalisation,
    pca_basis,
    scale_maps,
    smooth_curves,
    support_radius,
    time_step,
    widths,
)
from .saliency_online import SPREAD, TRACE_FRAMES, Online
from .saliency_presets import (
    AUTO_QUANTILE,
    AUTO_SECONDS,
    AUTO_SPEED_THRESHOLD,
    HISTORY_SECONDS,
    METHOD,
    PRESETS,
    STILL_SPEED,
    UPDATE_EVERY,
    auto_frames,
    auto_preset,
    choose_preset,
    moving,
    preset_sigma,
    resolve_params,
    step_speeds,
)

__all__ = ["extract", "Online", "METHOD", "PRESETS", "AUTO_SPEED_THRESHOLD", "FOOT_SIGMA",
           "CURVE_CUTOFF_HZ", "smooth_curves",
           "SCALES", "HISTORY_SECONDS", "Basis", "Moments", "MapStats", "moments", "pca_basis",
           "curvature", "kernel", "widths", "kernel_bank", "gaussian_means", "scale_maps",
           "local_max_mask", "map_stats", "normalisation", "combine", "curves_of", "maps_of",
           "curve_weights", "cluster_keyframes", "pick_keyframe", "match_basis",
           "choose_preset", "resolve_params", "cluster_size", "cluster_length", "support_radius",
           "auto_preset", "auto_frames", "AUTO_SECONDS", "AUTO_QUANTILE", "STILL_SPEED",
           "step_speeds",
           "moving", "REFERENCE_FPS", "UPDATE_EVERY", "preset_sigma", "time_step", "SPREAD",
           "TRACE_FRAMES"]


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
            variance_rule: bool, fps: float, moving: np.ndarray | None = None) -> _Curves:
    """Curves and maps of the rows `xs`; the PCA from the `moving` rows (default: all)."""
    basis = pca_basis(moments(xs if moving is None else xs[moving]), k, variance_rule)
    basis = fit_k(basis, k, contact)
    d = curves_of(basis, smooth_curves(xs, fps), smooth_curves(feet, fps), contact)
    s = maps_of(curvature(d, time_step(fps)), sigma, contact, frames_at(FOOT_SIGMA, fps))
    weights, foot = curve_weights(basis, contact)
    return _Curves(d, s, weights, foot, basis)


def extract(motion: Motion, *, sigma: DurationLike | None = None, k: int | None = None,
            contact: bool = True, preset: str = "auto", variance_rule: bool = False,
            features: Features | None = None,
            noise_cutoff_hz: float | None = DEFAULT_NOISE_CUTOFF_HZ) -> Keyframes:
    """Keyframes of `motion` by multiscale motion saliency (Halit & Capin);
    `sigma` a `Duration`, or frames as a plain number."""
    motion = without_lead(motion)  # a stream drops them too (`filters.FrontEnd`)
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
    info: dict[str, Any] = {"preset_requested": preset, "preset": used, "auto_speed": speed}
    n = motion.n_frames - first
    if n < 3:
        return Keyframes(METHOD, [], [], params, motion.n_frames, info)
    rot = _rotations(motion, features)
    xs = rot - rot[0]
    feet = features.foot_heights[first:] / features.body_height
    moving = motion_mask(detect_segments(motion, noise_cutoff_hz=noise_cutoff_hz),
                         motion.n_frames, first)[first:]
    if not moving.any():
        moving[:] = True  # no take at all: every frame counts
    cv = _curves(xs, feet, sigma, k, contact, variance_rule, fps, moving)
    a, thr = normalisation(map_stats(cv.s[moving], local_max_mask(cv.s)[moving]))
    sal = combine(cv.s, a)
    cand = (sal > thr) & moving[:, None]
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
