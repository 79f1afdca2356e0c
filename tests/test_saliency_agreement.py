"""Online saliency at its default lookahead gives the offline keys (real CMU clips): F1 of the
online keys against the offline keys at +-4 frames, median >= 0.9 and worst >= 0.75, and as
many keys (0.8-1.25x), default settings on both sides."""

from __future__ import annotations

from functools import cache

import numpy as np
import pytest
from cmu import DATA

from streamkey import variants as V
from streamkey.amc import read_motion
from streamkey.keyframes import KeyframeEvent
from streamkey.methods import saliency
from streamkey.methods.saliency_auto import AutoOnline

FEW = ["07_01.bvh", "05_02.bvh", "09_06.bvh", "16_11.bvh", "131_03.bvh"]
ALL = sorted(p.name for p in DATA.iterdir() if p.suffix in (".bvh", ".amc"))
F1_MEDIAN, F1_WORST, RATIO = 0.9, 0.75, (0.8, 1.25)


@cache
def scores(name: str) -> tuple[float, float]:
    """(F1 of the online keys against the offline keys, online / offline key count)."""
    m = V.clean_take(read_motion(DATA / name)).motion
    offline = np.asarray(saliency.extract(m).frames)
    kf = AutoOnline(m.skeleton, m.fps)
    online = np.array(sorted(e.frame for e in kf.push_block(m.frames()) + kf.flush()
                             if isinstance(e, KeyframeEvent)))
    return V.f1_against(offline, online, m.fps), len(online) / max(1, len(offline))


# Why online differs (measured on the 35 shared clips, online run with the preset offline chose,
# the whole-take value of one statistic put in at every decision; F1 median / worst): as is 0.808
# / 0.713; whole-take PCA basis 0.868 / 0.634; whole-take map means (the candidate thresholds
# mean(S_j)) 0.864 / 0.704; both 0.974 / 0.800; basis and every map statistic (the Itti maxima
# too) 1.000 / 0.979; basis and Itti maxima 0.877 / 0.683. The thresholds and the basis carry the
# difference, the Itti factors little. The whole-take map mean is not predictable from the stream
# so far: over the clips, whole-take / running mean after 1 s of motion has median 0.96 and log-sd
# 0.35 (2 s: 1.04, 0.26; 8 s: 1.04, 0.12), a take's own change of pace, with no bias a corpus
# prior could remove. A prior on the unit-free ratio map mean / mean of its local maxima (corpus
# log-sd 0.07-0.16) shrunk to the running mean over n0 frames moved the 5 clips' median 0.810 ->
# 0.807 / 0.800 / 0.800 / 0.836 (worst 0.787 -> 0.774 / 0.774 / 0.762 / 0.756) at n0 = 60 / 120 /
# 240 / 480: not adopted. "auto" clips that pick "high" lost more while the preset was decided
# 2 s into the motion, past the 1 s lookahead (F1 02_03 0.885 against 1.000 with the "high"
# keyframer alone); it is now decided 1 s into the motion.
@pytest.mark.xfail(strict=True, reason="measured: F1 median 0.810 worst 0.787")
def test_online_keys_at_the_default_lookahead_match_the_offline_keys() -> None:
    f1 = np.array([scores(c)[0] for c in FEW])
    assert np.median(f1) >= F1_MEDIAN and f1.min() >= F1_WORST, f1.round(3).tolist()


def test_online_at_the_default_lookahead_has_as_many_keys_as_offline() -> None:
    ratio = np.array([scores(c)[1] for c in FEW])
    assert RATIO[0] <= ratio.min() and ratio.max() <= RATIO[1], ratio.round(2).tolist()


@pytest.mark.slow
@pytest.mark.xfail(strict=True, reason="measured: F1 median 0.808 worst 0.713")
def test_online_keys_at_the_default_lookahead_match_the_offline_keys_on_every_shared_clip(
        ) -> None:
    f1 = np.array([scores(c)[0] for c in ALL])
    assert np.median(f1) >= F1_MEDIAN and f1.min() >= F1_WORST, f1.round(3).tolist()


# Met since the auto preset decides on the first second of motion (was 2 s: 0.70-1.42; the
# short runs lost their held-back "high" keys, 02_03 0.79).
@pytest.mark.slow
def test_online_at_the_default_lookahead_has_as_many_keys_as_offline_on_every_shared_clip(
        ) -> None:
    ratio = np.array([scores(c)[1] for c in ALL])
    assert RATIO[0] <= ratio.min() and ratio.max() <= RATIO[1], ratio.round(2).tolist()
