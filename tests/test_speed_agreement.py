"""Online speed at the default lookahead against the offline keys on every shared clip:
F1 at +-4 frames (median >= 0.9, worst >= 0.75) and the key count within 0.8-1.25x.

The misses are Ward + Mojena's, not the warm-up's: with near-equal intensities the cut flips
between the offline sample and the online one (05_13: the same 81 candidates, intensities
within 1.2 of each other, give a cut of 12.34 offline and 5.79 online; 131_03: 15.28 and
11.29). A prior threshold shrunk to the stream's cut (the median offline cut of the shared
clips, 4.37, weighted as 20 to 60 candidates) was measured too: median F1 0.923-0.939, 10-12
clips outside the count range, worst F1 0.18-0.29 (49_18, whose intensities are a tenth of
the others'), and 131_03 and 05_13 unchanged (their early intensities clear any prior); it
was not adopted. Measured as well, not adopted (it changes the paper's rule and the offline
keys of 14 of 35 clips): Mojena's cluster count with the optimal 1-D partition (least
within-cluster sum of squares) instead of Ward's greedy one, offline and online alike: median
F1 0.923, worst 0.483 (05_18), counts 0.55-3.14x with 11 clips outside; on the offline
variants of the 33 BVH clips, calibration worst F1 0.42 -> 0.60, stillness 0.55 -> 0.68,
60 Hz 0.55 -> 0.60.
"""

from __future__ import annotations

from functools import cache

import numpy as np
import pytest
from cmu import DATA, clips

from streamkey.amc import read_motion
from streamkey.evaluate import match_one_to_one
from streamkey.keyframes import KeyframeEvent
from streamkey.methods import speed

TOLERANCE = 4.0  # frames at 120 Hz
MEDIAN_F1, WORST_F1, RATIOS = 0.9, 0.75, (0.8, 1.25)


@cache
def rows() -> list[tuple[str, int, int, float]]:
    """Per shared clip: offline keys, online keys (default lookahead), F1."""
    out = []
    for name in clips():
        m = read_motion(DATA / name)
        off = speed.extract(m).frames
        kf = speed.Online(m.skeleton, m.fps)
        on = [e.frame for e in kf.push_block(m.frames()) + kf.flush()
              if isinstance(e, KeyframeEvent)]
        out.append((name, len(off), len(on), match_one_to_one(on, off, TOLERANCE)[3]))
    return out


@pytest.mark.slow
def test_online_agrees_with_offline_at_the_median_clip() -> None:
    f1 = [row[3] for row in rows()]
    assert np.median(f1) >= MEDIAN_F1, f"median F1 {np.median(f1):.3f}"  # measured 0.909


@pytest.mark.slow
@pytest.mark.xfail(strict=True, reason="measured: worst F1 0.364 (131_03), also 05_13 0.444, "
                   "05_18 0.516, 49_18 0.537; Ward + Mojena's cut flips between near-equal "
                   "samples")
def test_online_agrees_with_offline_on_every_clip() -> None:
    worst = min(rows(), key=lambda row: row[3])
    assert worst[3] >= WORST_F1, f"worst F1 {worst[3]:.3f} ({worst[0]})"


@pytest.mark.slow
@pytest.mark.xfail(strict=True, reason="measured: online/offline key counts 0.37 (49_18: 11 "
                   "vs 30) to 4.50 (131_03: 18 vs 4; 05_13: 14 vs 4), 14 of 35 clips outside "
                   "0.8-1.25")
def test_online_keeps_as_many_keys_as_offline_on_every_clip() -> None:
    ratios = {name: on / off for name, off, on, _ in rows()}
    outside = {n: round(r, 2) for n, r in ratios.items() if not RATIOS[0] <= r <= RATIOS[1]}
    assert not outside, outside
