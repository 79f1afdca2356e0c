"""Adaptive speed-minima keyposes — Miura et al. 2014, "Adaptive keypose extraction from
motion capture data" (section 3), offline and online.

Offline: `extract(motion)`. Definitions this module settles (the paper leaves them open):

- Speed (Miura eq. 3): the 16 joints of `MIURA_ROLES` in the pelvis frame, divided by body
  height, stacked into one 48-vector p(n) per captured frame and HP-filtered at f_c (eq. 2);
  v(n) = |p_F(n+1) - p_F(n)| / dt, the Euclidean norm over all 48 coordinates (eq. 3). v has
  one value fewer than the motion has captured frames and v(n) is reported at frame n (the
  first frame of the forward difference). A first frame that is a reference T-pose (or an
  all-zero dropout, `motion.reference_lead`) is not captured motion and is left out, by
  `extract` (`motion.without_lead`) and by a stream (the front end drops it,
  `filters.FrontEnd`): its one-frame jump would be the largest speed of all and leave one
  cluster above Mojena's cut (07_05 streamed with its reference frame: 1 key instead of 6).
- Rest: candidates (local minima of v) and the minima of every scale's trend lie at speeds of
  at least `REST_SPEED` (0.02 body heights/s); below it an exact hold has only rounding noise
  and HP ringing, whose minima counted as candidates and moved Mojena's cut-off.
- Correspondence (Miura Fig. 3): two minima of adjacent lists (the candidates and the f_max
  minima, then scale to scale) correspond when each is the other's nearest in time (a tie:
  the earlier; `nearest_pairs`). Chains start at the candidates, are matched to the f_max
  minima, then scale to scale; a minimum with no partner ends its chain, and the candidate
  gets u = 0 at every coarser scale. The correspondence used to be the
  order-preserving one-to-one matching that pairs every element of the shorter list and
  minimises the total absolute time difference (`match_minima`, a DP). With the sensor-noise
  front end on, the candidates and the f_max minima are nearly the same lists (session 07:
  184 and 179), so that matching had almost no slack: one extra candidate shifted every
  later pair by one step until the next surplus (candidates paired with a minimum 20-60
  frames away while their own lay 0-1 frames away), the intensities of a walk's two minima
  per step swapped, and which of them became keys depended on where the window began.
  Mutual nearest minima are local: an extra or missing minimum leaves its neighbours' pairs
  alone. Measured (default settings, front end on), DP -> mutual nearest: online/offline
  agreement of sessions after 10 s, worst F1 0.683 (session 07) -> 0.887 (session 131;
  session 07 0.992, every session up); per clip, median F1 0.952 -> 0.963; recording
  variants, calibration before, worst F1 offline 0.400 -> 0.889 and online 0.667 -> 0.846;
  no variant cell lost; heel strikes of the 10 annotated walks unchanged (F mean 0.914,
  lowest 0.75, the same key count and F on every walk).
- The keypose cut, a measured departure from Miura's rule: keyposes are the candidates whose
  U is above 0.4 x the 95th percentile of the sample's intensities (`quantile_threshold`,
  `cut="quantile"`, the default). Miura cuts with Ward's clustering of U and Mojena's
  stopping rule one (`cut="mojena"`, below). That cluster count jumps between nearly
  identical samples (05_13: the same 81 candidates, a cut of 12.3 offline and 5.8 online),
  so online keys and the keys of a take recorded another way flipped with it. The quantile
  cut moves continuously with its sample: a verdict changes only for a candidate whose own U
  is near the threshold. Measured on the 35 shared clips, Mojena -> quantile: heel strikes of
  the 10 annotated walks F mean 0.937 -> 0.937, lowest 0.75 -> 0.75, one key per step (+-1)
  on 10 of 10 both; online (default lookahead) against offline F1 median 0.909 -> 0.952,
  worst 0.364 -> 0.651, key ratio 0.37-4.50 -> 0.83-2.07 (clips outside 0.8-1.25: 14 -> 8);
  recording variants (F1 against the clean take, mean / worst): 60 Hz offline 0.915 / 0.55
  -> 0.944 / 0.71, 30 Hz offline 0.821 / 0.40 -> 0.881 / 0.55, calibration before offline
  0.882 / 0.00 -> 0.968 / 0.83, stillness after offline 0.919 / 0.55 -> 0.977 / 0.86, online
  likewise. Offline keys change on 22 of 35 clips (F1 0.50-0.97 against Mojena's; 05_13 and
  131_03: 4 -> 12 keys, 09_01: 7 -> 3). Neighbouring constants (quantile 0.93-0.97, fraction
  0.35-0.45) give the same walks' scores. Tried and measured, not adopted: Ward forced to two
  clusters (agreement worst 0.364), Otsu's two classes of log U and Ward's two of log U
  (walks F 0.82-0.83, 5 of 10 walks off by more than one step), the widest gap of the Ward
  levels (agreement worst 0.488, 12 clips outside), Mojena's rule on log levels, multiples
  of the median, mean or RMS of U (walks F 0.71-0.95 with 2-9 of 10 step counts) and other
  quantiles (0.75-0.9: fewer variant cells met).
- Miura's cut, `cut="mojena"`: Mojena's stopping rule one (Mojena 1977) on the Ward fusion
  levels alpha (squared scipy heights, the Lance-Williams levels): cut-off mean(alpha) +
  k * std(alpha, ddof=1); the number of clusters is one more than the number of levels above
  it (fewer than 3 candidates: one cluster). The dropped cluster (the one with a zero
  intensity, else the lowest mean) becomes an intensity threshold: keyposes are the
  candidates with U above the dropped cluster's largest intensity (0 for a single cluster).
  On every shared clip Ward's clusters are intervals of intensity, so this is the paper's
  rule (`info["contiguous_clusters"]` checks). From `WARD_1D_FROM` values on, Ward runs as
  greedy merging of sorted neighbours (`ward_1d`, O(n log n); in 1-D the closest pair is
  always adjacent) instead of scipy's O(n^2) linkage: same levels to rounding, the same keys
  on every shared clip and at 100,000 frames (3.2 -> 2.0 s CPU there); online, ~550 values
  per update: 3.7 -> 1.2 ms.

Online: `Online` (defined in `speed_online`, its state in named parts in `speed_state`), the
windowed replacements of these global steps with a bounded lookahead; with a lookahead of at
least the stream's length it gives the offline result, bit for bit.

HP factors (`signal.hp_factor`, offline and online alike): LAPACK's banded Cholesky factor in
its first 20 lambda^(1/4) columns, then its converged column (within LAPACK's own ~1e-11
rounding noise there), then the bottom corner: O(n) without a factorisation of length n. Same
keys as the LAPACK factorisation on every shared clip and at 100,000 frames (intensities within
1.4e-7 relative). Offline solves go through LAPACK (`HPBank`, which holds its lambdas only);
the online kernels read the same first and converged columns from `packed_factors` (2.4 MB
at 120 fps with the defaults, shared by every stream with equal parameters, never pickled).
Shared compiled steps (`speed_kernels`, offline and online alike, exact): the chains of
mutual nearest minima, the 1-D Ward (`ward_1d`) and the rest of Mojena's rule. Memory per
keyframer is bounded by the window (positions, speeds), the carried forward values (the
region's rows x 144 lambdas, 0.47 MB) and the cut-off sample (the candidates of
`cutoff_history` frames); pickled after 30 s: 1.44-1.51 MB.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from ..features import DEFAULT_NOISE_CUTOFF_HZ, Features, compute_features
from ..keyframes import Keyframes
from ..motion import Motion, without_lead
from ..roles import MIURA_ROLES
from ..segments import Segment, motion_mask
from .speed_chains import (
    BAND_BUDGET,
    CUTS,
    WARD_1D_FROM,
    Chain,
    MojenaResult,
    check_cut,
    intensities,
    match_minima,
    mojena_threshold,
    nearest_pairs,
    quantile_threshold,
    ward_1d,
)
from .speed_online import CUTOFF_HISTORY, HISTORY, LOOKAHEAD, MAX_HOP, Online
from .speed_scales import (
    METHOD,
    REST_SPEED,
    HPBank,
    candidates_of,
    check_params,
    packed_factors,
    scale_frequencies,
    scale_lambdas,
    scale_minima,
    scale_minimum,
    settle_frames,
    speed_signal,
    speed_tail,
)

__all__ = ["extract", "scale_frequencies", "speed_signal", "HPBank", "scale_minima",
           "match_minima", "intensities", "mojena_threshold", "MojenaResult", "METHOD", "Online",
           "scale_lambdas", "settle_frames", "ward_1d", "WARD_1D_FROM", "scale_minimum", "Chain",
           "speed_tail", "packed_factors", "REST_SPEED", "candidates_of", "LOOKAHEAD", "MAX_HOP",
           "HISTORY", "CUTOFF_HISTORY", "BAND_BUDGET", "quantile_threshold", "CUTS",
           "nearest_pairs"]


def _positions(motion: Motion, features: Features | None, first: int | None = None
               ) -> np.ndarray:
    feats = features if features is not None else compute_features(motion)
    p = feats.role_positions(MIURA_ROLES)[motion.first_frame if first is None else first :]
    return p.reshape(len(p), -1) / feats.body_height


def extract(motion: Motion, *, features: Features | None = None, f_c: float = 10.0,
            f_max: float = 8.0, f_min: float = 0.2, r: float = 0.95,
            mojena_k: float = 2.75, cut: str = "quantile",
            noise_cutoff_hz: float | None = DEFAULT_NOISE_CUTOFF_HZ,
            segments: Sequence[Segment] | None = None) -> Keyframes:
    """Keyposes at speed minima whose multiscale intensity clears the cut (Miura 3): by
    default the quantile cut (`quantile_threshold`), with `cut="mojena"` Miura's Ward +
    Mojena cut (`mojena_threshold`, its constant `mojena_k`).

    `segments` (the session segments of `motion`, `segments.detect_segments`): candidates
    outside takes (in calibration holds and still stretches) are left out of Ward + Mojena's
    sample, so that a session state does not move the cut-off; they still get keys by it.
    `Online.note_segment` does the same with the segment events of a stream.
    """
    motion = without_lead(motion)  # a stream drops them too (`filters.FrontEnd`)
    check_params(f_c, f_max, f_min, r, mojena_k)
    cut = check_cut(cut)
    features = features or compute_features(motion, noise_cutoff_hz=noise_cutoff_hz)
    params: dict[str, Any] = {"f_c": f_c, "f_max": f_max, "f_min": f_min, "r": r,
                              "mojena_k": mojena_k, "cut": cut}
    dt = motion.frame_time
    off = motion.first_frame
    v = speed_signal(_positions(motion, features, off), dt, f_c)
    freqs = scale_frequencies(f_max, f_min, r)
    bank = HPBank(scale_lambdas(freqs, dt))
    cand = candidates_of(v)
    u = intensities(cand, scale_minima(v, bank))
    in_take = np.ones(len(cand), dtype=bool)
    if segments is not None:
        in_take = motion_mask(segments, motion.n_frames, motion.first_frame)[cand + off]
    info: dict[str, Any] = {"candidates": cand + off, "intensities": u, "cut": cut,
                            "n_scales": len(freqs)}
    if cut == "mojena":
        res = mojena_threshold(u[in_take], mojena_k)
        threshold = res.threshold
        info.update(n_clusters=res.n_clusters, level_cutoff=res.level_cutoff,
                    contiguous_clusters=res.contiguous)
    else:
        threshold = quantile_threshold(u[in_take])
    info["threshold"] = threshold
    keep = u > threshold
    return Keyframes(METHOD, cand[keep] + off, u[keep], params, motion.n_frames, info)

