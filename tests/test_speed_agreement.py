"""Online speed at the default lookahead against the offline keys on every shared clip:
F1 at +-4 frames (median >= 0.9, worst >= 0.75) and the key count within 0.8-1.25x.

With Miura's Ward + Mojena cut (`cut="mojena"`) the cluster count flips between nearly equal
samples (05_13: the same 81 candidates give a cut of 12.34 offline and 5.79 online): median
F1 0.909, worst 0.364 (131_03), counts 0.37-4.50x with 14 clips outside. The default quantile
cut moves continuously with its sample. With the sensor-noise front end on and minima paired
by mutual nearest neighbours: median 0.963, worst 0.556 (05_02), counts 0.89-2.44x with 6
clips outside (05_02 12 vs 6, 05_13 15 vs 8, 05_18 22 vs 9, 06_02 10 vs 6, 06_15 7 vs 4,
131_03 16 vs 11). What is left is the warm-up: a clip that starts calm gets a low cut from
its first seconds (05_02: online cut-offs 0.5-1.6 over its first 3.5 s, offline 7.6).
Measured as well, not adopted: a prior 95th percentile measured on the corpus (17.26, the
median over the 35 shared clips offline), shrunk to the stream's own in log space with the
weight of W candidates. W = 8: worst F1 0.667 (05_02), counts 0.54 (49_18) to 1.89. Before
the pairing, W = 20: worst 0.375 and count 0.23 on 49_18, whose intensities are a twentieth
of the others' (its 95th percentile 0.81); W = 60: 49_18 0.267. A calm start and a calm
clip look the same until the motion comes; no goal cell is gained. Also not adopted:
Mojena's count with the optimal 1-D partition (worst 0.483).
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
    assert np.median(f1) >= MEDIAN_F1, f"median F1 {np.median(f1):.3f}"  # measured 0.963


@pytest.mark.slow
@pytest.mark.xfail(strict=True, reason="measured: worst F1 0.556 (05_02), also 05_18 0.581, "
                   "05_13 0.696; clips that start calm get a low cut in their first seconds")
def test_online_agrees_with_offline_on_every_clip() -> None:
    worst = min(rows(), key=lambda row: row[3])
    assert worst[3] >= WORST_F1, f"worst F1 {worst[3]:.3f} ({worst[0]})"


@pytest.mark.slow
@pytest.mark.xfail(strict=True, reason="measured: online/offline key counts 0.89 to 2.44 "
                   "(05_18: 22 vs 9; 05_02: 12 vs 6; 05_13: 15 vs 8), 6 of 35 clips outside "
                   "0.8-1.25")
def test_online_keeps_as_many_keys_as_offline_on_every_clip() -> None:
    ratios = {name: on / off for name, off, on, _ in rows()}
    outside = {n: round(r, 2) for n, r in ratios.items() if not RATIOS[0] <= r <= RATIOS[1]}
    assert not outside, outside
