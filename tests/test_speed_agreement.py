"""Online speed at the default lookahead against the offline keys on every shared clip:
F1 at +-4 frames (median >= 0.9, worst >= 0.75) and the key count within 0.8-1.25x.

With Miura's Ward + Mojena cut (`cut="mojena"`) the cluster count flips between nearly equal
samples (05_13: the same 81 candidates give a cut of 12.34 offline and 5.79 online): median
F1 0.909, worst 0.364 (131_03), counts 0.37-4.50x with 14 clips outside. The default quantile
cut moves continuously with its sample: median 0.952, worst 0.651 (05_18), counts 0.83-2.07x
with 8 clips outside. What is left is the warm-up: a clip that starts calm gets a low cut
from its first seconds (05_18: 29 keys online, 14 offline). Measured as well, not adopted: a
prior threshold shrunk to the stream's cut (worst F1 0.18-0.29 on 49_18, whose intensities
are a tenth of the others'), and Mojena's count with the optimal 1-D partition (worst 0.483).
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
    assert np.median(f1) >= MEDIAN_F1, f"median F1 {np.median(f1):.3f}"  # measured 0.952


@pytest.mark.slow
@pytest.mark.xfail(strict=True, reason="measured: worst F1 0.651 (05_18), also 05_11 0.727, "
                   "05_02 0.741; clips that start calm get a low cut in their first seconds")
def test_online_agrees_with_offline_on_every_clip() -> None:
    worst = min(rows(), key=lambda row: row[3])
    assert worst[3] >= WORST_F1, f"worst F1 {worst[3]:.3f} ({worst[0]})"


@pytest.mark.slow
@pytest.mark.xfail(strict=True, reason="measured: online/offline key counts 0.83 to 2.07 "
                   "(05_18: 29 vs 14; 05_11: 7 vs 4; 05_02: 17 vs 10), 8 of 35 clips outside "
                   "0.8-1.25")
def test_online_keeps_as_many_keys_as_offline_on_every_clip() -> None:
    ratios = {name: on / off for name, off, on, _ in rows()}
    outside = {n: round(r, 2) for n, r in ratios.items() if not RATIOS[0] <= r <= RATIOS[1]}
    assert not outside, outside
